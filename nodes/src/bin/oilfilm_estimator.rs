//! The `estimator` node (see `oilfilm_nodes::shell::estimator_main`).

fn main() -> std::process::ExitCode {
    match oilfilm_nodes::shell::estimator_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-estimator: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
