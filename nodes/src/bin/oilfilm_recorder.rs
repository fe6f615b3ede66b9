//! The `recorder` node (see `oilfilm_nodes::shell::recorder_main`).

fn main() -> std::process::ExitCode {
    match oilfilm_nodes::shell::recorder_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-recorder: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
