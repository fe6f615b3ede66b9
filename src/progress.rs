//! A progress line for long runs.

use std::io::{IsTerminal, Write};

/// A progress line on stderr, only when stderr is a terminal.
pub struct Progress {
    label: String,
    enabled: bool,
    last: i64,
}

impl Progress {
    pub fn new(label: &str) -> Self {
        Self { label: label.to_string(), enabled: std::io::stderr().is_terminal(), last: -1 }
    }

    pub fn update(&mut self, fraction: f64) {
        let pct = (fraction * 100.0).floor() as i64;
        if self.enabled && pct != self.last {
            self.last = pct;
            let bar = (fraction * 30.0).round() as usize;
            eprint!("\r{} [{:<30}] {pct:>3} %", self.label, "#".repeat(bar.min(30)));
            let _ = std::io::stderr().flush();
        }
    }

    pub fn finish(&mut self) {
        if self.enabled {
            eprintln!();
        }
    }
}
