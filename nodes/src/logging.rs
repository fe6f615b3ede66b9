//! A node's log: to stderr (plain text when stderr is not a terminal, so a log file or a
//! pipe gets no colour codes) and, once the node is on DDS, to `/rosout` as
//! `rcl_interfaces/msg/Log` with the node's logger name (`oilfilm.exciter` for
//! `/oilfilm/exciter`, as rclcpp names it), where rqt_console, Foxglove and rclpy read it.
//!
//! `RUST_LOG` filters both (default: info, and warnings of the DDS stack). The DDS stack's
//! own lines stay on stderr: they are about the transport `/rosout` travels on.

use std::cell::Cell;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use ros2_client::{Log, Publisher};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::Layer;

use oilfilm_graph::stamp::Stamp;

/// The node's `/rosout` writer and logger name, once it has one.
static ROSOUT: Mutex<Option<(Arc<Publisher<Log>>, String)>> = Mutex::new(None);

/// The node's ROS time when it follows `/clock` (ns), or [`WALL`].
static SIM_NOW: AtomicI64 = AtomicI64::new(WALL);
const WALL: i64 = i64::MIN;

thread_local! {
    /// Set while an event is being published, so that what the transport logs meanwhile
    /// is not published in turn.
    static PUBLISHING: Cell<bool> = const { Cell::new(false) };
}

/// The default filter: our info lines; the DDS stack's warnings. ros2-client's warning that
/// `ROS_DISTRO` is unset is left out: nothing here is built against a ROS install.
const DEFAULT_FILTER: &str = "info,rustdds=warn,ros2_client=warn,ros2_client::distributions=error";

/// Logs to stderr and, once [`attach`] is called, to `/rosout`.
pub fn init() {
    init_with(DEFAULT_FILTER);
}

/// [`init`] with another filter than the nodes' when `RUST_LOG` is unset: a command that runs
/// the nodes in its own process (`oilfilm identify --stream`) shows their warnings, not
/// their info lines, beside its own output.
pub fn init_with(default_filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    let fmt = tracing_subscriber::fmt::layer().with_writer(std::io::stderr).with_ansi(std::io::stderr().is_terminal());
    let _ = tracing_subscriber::registry().with(filter).with(fmt).with(RosoutLayer).try_init();
}

/// From now on, log lines also go to `writer` (the node's `/rosout` publisher) under
/// `logger_name`.
pub fn attach(writer: Arc<Publisher<Log>>, logger_name: String) {
    *ROSOUT.lock().unwrap_or_else(PoisonError::into_inner) = Some((writer, logger_name));
}

/// No more `/rosout` (the node is leaving DDS).
pub fn detach() {
    *ROSOUT.lock().unwrap_or_else(PoisonError::into_inner) = None;
}

/// The node's clock for log stamps: `Some(t)` while it follows `/clock`, `None`: the wall
/// clock.
pub fn set_sim_time(now: Option<Stamp>) {
    SIM_NOW.store(now.map_or(WALL, |t| t.0), Ordering::Relaxed);
}

/// `oilfilm.exciter` for `/oilfilm/exciter`: the logger name rclcpp gives a node.
pub fn logger_name(fully_qualified: &str) -> String {
    fully_qualified.trim_start_matches('/').replace('/', ".")
}

struct RosoutLayer;

/// An event's message and its other fields (`key=value`), the `node` field left out (the
/// logger name says it).
#[derive(Default)]
struct Text {
    message: String,
    fields: Vec<String>,
}

impl Visit for Text {
    fn record_str(&mut self, field: &Field, value: &str) {
        match field.name() {
            "message" => self.message = value.to_string(),
            "node" => {}
            name => self.fields.push(format!("{name}={value}")),
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        match field.name() {
            "message" => self.message = format!("{value:?}"),
            "node" => {}
            name => self.fields.push(format!("{name}={value:?}")),
        }
    }
}

impl<S: Subscriber> Layer<S> for RosoutLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        let target = meta.target();
        if target.starts_with("rustdds") || target.starts_with("ros2_client") || PUBLISHING.with(Cell::get) {
            return;
        }
        let Some((writer, name)) = ROSOUT.lock().unwrap_or_else(PoisonError::into_inner).clone() else { return };
        let mut text = Text::default();
        event.record(&mut text);
        let msg = if text.fields.is_empty() { text.message } else { format!("{} ({})", text.message, text.fields.join(", ")) };
        let level = match *meta.level() {
            Level::ERROR => Log::ERROR,
            Level::WARN => Log::WARN,
            Level::INFO => Log::INFO,
            _ => Log::DEBUG,
        };
        let sim = SIM_NOW.load(Ordering::Relaxed);
        let stamp = if sim == WALL { Stamp::now() } else { Stamp(sim) };
        let log = Log {
            stamp: ros2_client::builtin_interfaces::Time::from_nanos(stamp.0),
            level,
            name,
            msg,
            file: meta.file().unwrap_or_default().to_string(),
            function: meta.module_path().unwrap_or_default().to_string(),
            line: meta.line().unwrap_or(0),
        };
        PUBLISHING.with(|p| p.set(true));
        // A log line that cannot reach /rosout is still on stderr.
        let _ = writer.publish(log);
        PUBLISHING.with(|p| p.set(false));
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn logger_names_are_rclcpps() {
        assert_eq!(super::logger_name("/oilfilm/exciter"), "oilfilm.exciter");
        assert_eq!(super::logger_name("/talker"), "talker");
    }
}
