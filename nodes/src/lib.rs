//! The oilfilm nodes on ROS 2: the DDS runner ([`runner`]) on ros2-client ([`dds`]), the
//! node binaries (`oilfilm-exciter`, `-daq`, `-conditioner`, `-estimator`, `-recorder`,
//! `-player`, each [`runner::main`] for its node of `oilfilm-graph`), and the process
//! supervisor behind `oilfilm launch` ([`supervisor`]). Everything else (the nodes, their
//! parameters, launch files, the in-memory and bag runners) is `oilfilm-graph`, which has
//! no middleware.

pub mod dds;
pub mod logging;
pub mod parameters;
pub mod runner;
pub mod supervisor;
