//! The `daq` node on DDS (`oilfilm_graph::daq::Daq`).

fn main() -> std::process::ExitCode {
    oilfilm_nodes::runner::main::<oilfilm_graph::daq::Daq>()
}
