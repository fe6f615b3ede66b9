//! The oilfilm node graph, without a middleware: the nodes (`exciter`, `daq`, `conditioner`,
//! `estimator`, and the bag `recorder` and `player`), the one trait they share
//! ([`node::Node`]), launch files and parameters as data ([`launch`], [`params`]), and two
//! of the three runners: in memory ([`runner::memory`]) and on a bag's messages
//! ([`runner::bag`]). The third, on DDS through ros2-client, is the `oilfilm-nodes` crate,
//! the only one that depends on a middleware.
//!
//! Each node is a core (plain Rust, no I/O, no clock: time is passed in) and a turn that
//! moves messages between the core and its ports ([`ports`]), so live, replay and tests run
//! the very same code and a replayed recording gives the live coefficients bit for bit.
//!
//! Topics, types and QoS: [`topics`]. Frame: x horizontal, y vertical up (see the .msg
//! files in `msgs/`).

pub mod conditioner;
pub mod daq;
pub mod error;
pub mod estimator;
pub mod exciter;
pub mod foreign;
pub mod launch;
pub mod lines;
pub mod node;
pub mod params;
pub mod player;
pub mod ports;
pub mod recorder;
pub mod replay;
pub mod runner;
pub mod stamp;
pub mod topics;

pub use error::NodeError;
pub use node::{Connect, Node, Start, Turn};
