//! What the byte-level fuzz loops share (CDR messages, foreign records, DAQ lines): the
//! case count and first seed from the environment, byte mutations, and an allocator that
//! reports the largest single allocation a case asked for. Included with `#[path]` by the
//! test crates that fuzz, so each loop reads `OILFILM_FUZZ_CASES` and `OILFILM_FUZZ_SEED`
//! the same way: case `k` runs from seed `OILFILM_FUZZ_SEED + k` (printed on failure), so
//! `OILFILM_FUZZ_SEED=<seed> OILFILM_FUZZ_CASES=1` runs that case alone.

#![allow(dead_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `(first seed, cases)`: `OILFILM_FUZZ_SEED` and `OILFILM_FUZZ_CASES`, else the loop's own.
pub fn settings(seed: u64, cases: u64) -> (u64, u64) {
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<u64>().ok());
    (env("OILFILM_FUZZ_SEED").unwrap_or(seed), env("OILFILM_FUZZ_CASES").unwrap_or(cases))
}

/// Whether a loop of `cases` is judged on its mix of outcomes (some read, many refused,
/// every kind of refusal reached) besides each case on itself: the default loops are; a case
/// replayed alone (`OILFILM_FUZZ_CASES=1`) or a handful is judged only on itself, so that its
/// replay fails exactly when the case does.
pub fn mix_is_judged(cases: u64) -> bool {
    cases >= 1000
}

/// The generator of one case.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// Values a length or count field is set to: the ones that catch an unchecked length.
const HUGE: [u64; 8] = [0xFFFF_FFFF, 0x7FFF_FFFF, 0x8000_0000, 0xFFFF_FFFF_FFFF_FFFF, 0x7FFF_FFFF_FFFF_FFFF, 0x0001_0000, 0, 1];

/// One mutation of `bytes`; returns what it did (for the failure message).
pub fn mutate_bytes(rng: &mut ChaCha8Rng, bytes: &mut Vec<u8>) -> String {
    let len = bytes.len();
    if len == 0 {
        let n = rng.random_range(1..16);
        bytes.extend((0..n).map(|_| rng.random::<u8>()));
        return format!("{n} random bytes into an empty input");
    }
    match rng.random_range(0..12) {
        0 | 1 => {
            let i = rng.random_range(0..len);
            let bit = rng.random_range(0..8);
            bytes[i] ^= 1 << bit;
            format!("bit {bit} of byte {i} flipped")
        }
        2 => {
            let i = rng.random_range(0..len);
            bytes[i] = rng.random();
            format!("byte {i} set to {:#04x}", bytes[i])
        }
        3 | 4 => {
            let at = rng.random_range(0..len);
            bytes.truncate(at);
            format!("cut at byte {at}")
        }
        // A length or count field set huge (or zero): a 4- or 8-byte word, either byte
        // order, at a 4-aligned offset most of the time (where such fields sit).
        5..=7 => {
            let wide = rng.random_bool(0.3);
            let w = if wide { 8 } else { 4 };
            if len < w {
                bytes.truncate(0);
                return "emptied (too short for a word)".into();
            }
            let mut at = rng.random_range(0..=len - w);
            if rng.random_bool(0.8) {
                at -= at % 4;
            }
            let v = match rng.random_range(0..10) {
                0 => len as u64 + rng.random_range(1..64),
                1 => rng.random(),
                k => HUGE[k - 2],
            };
            let big = rng.random_bool(0.2);
            let word: Vec<u8> = match (wide, big) {
                (true, false) => v.to_le_bytes().to_vec(),
                (true, true) => v.to_be_bytes().to_vec(),
                (false, false) => (v as u32).to_le_bytes().to_vec(),
                (false, true) => (v as u32).to_be_bytes().to_vec(),
            };
            bytes[at..at + w].copy_from_slice(&word);
            format!("{w}-byte word at {at} set to {v:#x}{}", if big { " (big-endian)" } else { "" })
        }
        8 => {
            let at = rng.random_range(0..=len);
            let n = rng.random_range(1..32);
            bytes.splice(at..at, (0..n).map(|_| rng.random::<u8>()));
            format!("{n} random bytes inserted at {at}")
        }
        9 => {
            let a = rng.random_range(0..len);
            let b = (a + rng.random_range(1..64)).min(len);
            bytes.drain(a..b);
            format!("bytes {a}..{b} deleted")
        }
        // A stretch duplicated (a segment, a record, an element repeated).
        10 => {
            let a = rng.random_range(0..len);
            let b = (a + rng.random_range(1..=len.min(512))).min(len);
            let to = rng.random_range(0..=len);
            let piece = bytes[a..b].to_vec();
            bytes.splice(to..to, piece);
            format!("bytes {a}..{b} copied to {to}")
        }
        _ => {
            let n = rng.random_range(0..64);
            *bytes = (0..n).map(|_| rng.random::<u8>()).collect();
            format!("replaced by {n} random bytes")
        }
    }
}

/// One to four mutations; returns what they did.
pub fn mutate_some(rng: &mut ChaCha8Rng, bytes: &mut Vec<u8>) -> String {
    let n = rng.random_range(1..5);
    (0..n).map(|_| mutate_bytes(rng, bytes)).collect::<Vec<_>>().join(", then ")
}

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    /// The seed of the case this thread runs, for the message of a refused allocation.
    static CASE: Cell<u64> = const { Cell::new(0) };
}

/// A single request above this is refused (the process then aborts, a seed's message on
/// stderr first): a length read from the input and trusted. Far above anything a case of
/// these loops needs, far below what would make the machine swap.
pub const REFUSED_ALLOCATION: usize = 1 << 30;

/// The system allocator, noting the largest single request of each thread: a test binary
/// that fuzzes makes it its `#[global_allocator]`, and [`largest_allocation`] reads it for
/// one case. A length read from the input and trusted shows as a request of gigabytes, and
/// one above [`REFUSED_ALLOCATION`] ends the process with the case's seed on stderr (an
/// allocator cannot unwind, so it cannot be a panic the loop catches).
pub struct Counting;

// SAFETY: every call goes to `System` unchanged, but for a refusal, which returns null as an
// allocator that is out of memory does. The thread-locals are const-initialised `Cell`s
// without a destructor, so touching them allocates nothing and cannot recurse; the refusal's
// message is formatted on the stack and written to unbuffered stderr.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !note(layout.size()) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !note(layout.size()) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if !note(new_size) {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Notes a request; false (after saying so on stderr) when it is refused.
fn note(size: usize) -> bool {
    // `try_with`: during a thread's teardown the slot may be gone; nothing is noted then.
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
    if size <= REFUSED_ALLOCATION {
        return true;
    }
    struct Stack {
        buf: [u8; 160],
        len: usize,
    }
    impl std::fmt::Write for Stack {
        fn write_str(&mut self, s: &str) -> std::fmt::Result {
            let n = s.len().min(self.buf.len() - self.len);
            self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
            self.len += n;
            Ok(())
        }
    }
    let mut m = Stack { buf: [0; 160], len: 0 };
    let seed = CASE.try_with(Cell::get).unwrap_or(0);
    let _ = std::fmt::Write::write_fmt(&mut m, format_args!("\nfuzz: a single allocation of {size} bytes refused in the case of seed {seed}\n"));
    let _ = std::io::Write::write_all(&mut std::io::stderr(), &m.buf[..m.len]);
    false
}

/// Runs `f` as the case of `seed` and gives its result with the largest single allocation
/// (bytes) this thread asked for meanwhile (0 when the binary's allocator is not
/// [`Counting`]).
pub fn largest_allocation<R>(seed: u64, f: impl FnOnce() -> R) -> (R, usize) {
    CASE.with(|c| c.set(seed));
    let before = LARGEST.with(|l| l.replace(0));
    let r = f();
    let largest = LARGEST.with(|l| l.replace(before.max(l.get())));
    (r, largest)
}
