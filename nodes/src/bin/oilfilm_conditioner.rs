//! The `conditioner` node (see `oilfilm_nodes::shell::conditioner_main`).

fn main() -> std::process::ExitCode {
    match oilfilm_nodes::shell::conditioner_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-conditioner: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
