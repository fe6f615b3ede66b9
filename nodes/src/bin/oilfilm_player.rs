//! The `player` node on DDS (`oilfilm_graph::player::Player`).

fn main() -> std::process::ExitCode {
    oilfilm_nodes::runner::main::<oilfilm_graph::player::Player>()
}
