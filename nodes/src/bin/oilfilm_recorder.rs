//! The `recorder` node on DDS (`oilfilm_graph::recorder::Recorder`).

fn main() -> std::process::ExitCode {
    oilfilm_nodes::runner::main::<oilfilm_graph::recorder::Recorder>()
}
