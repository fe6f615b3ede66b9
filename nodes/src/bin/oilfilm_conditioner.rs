//! The `conditioner` node on DDS (`oilfilm_graph::conditioner::Conditioner`).

fn main() -> std::process::ExitCode {
    oilfilm_nodes::runner::main::<oilfilm_graph::conditioner::Conditioner>()
}
