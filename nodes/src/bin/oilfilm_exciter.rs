//! The `exciter` node on DDS (`oilfilm_graph::exciter::Exciter`).

fn main() -> std::process::ExitCode {
    oilfilm_nodes::runner::main::<oilfilm_graph::exciter::Exciter>()
}
