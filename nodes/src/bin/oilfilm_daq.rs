//! The `daq` node (see `oilfilm_nodes::shell::daq_main`).

fn main() -> std::process::ExitCode {
    match oilfilm_nodes::shell::daq_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-daq: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
