//! The oilfilm ROS 2 nodes: `exciter`, `daq`, `conditioner` and `estimator`, thin shells over
//! the physics and identification crates, and the bag `recorder` and `player`.
//!
//! Each node is a core (plain Rust, no ROS, no I/O, no clock: time is passed in) and a
//! `poll` ([`poll`]) that moves messages between the core and its ports ([`ports`]). The
//! ports are DDS topics through ros2-client ([`dds`]) in the node binaries, in-memory
//! buses in tests, or a bag's messages on replay, so live, replay and tests run the very
//! same code and a replayed recording gives the live coefficients bit for bit.
//!
//! Topics, types and QoS: [`topics`]. Frame: x horizontal, y vertical up (see the .msg
//! files in `msgs/`).

pub mod conditioner;
pub mod daq;
pub mod error;
pub mod estimator;
pub mod exciter;
pub mod harness;
pub mod launch;
pub mod params;
pub mod player;
pub mod recorder;
pub mod dds;
pub mod shell;
pub mod poll;
pub mod ports;
pub mod replay;
pub mod stamp;
pub mod topics;

pub use error::NodeError;
