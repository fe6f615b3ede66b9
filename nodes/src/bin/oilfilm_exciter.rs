//! The `exciter` node (see `oilfilm_nodes::shell::exciter_main`).

fn main() -> std::process::ExitCode {
    match oilfilm_nodes::shell::exciter_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-exciter: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
