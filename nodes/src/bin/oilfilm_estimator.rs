//! The `estimator` node on DDS (`oilfilm_graph::estimator::Estimator`).

fn main() -> std::process::ExitCode {
    oilfilm_nodes::runner::main::<oilfilm_graph::estimator::Estimator>()
}
