//! The `player` node (see `oilfilm_nodes::shell::player_main`).

fn main() -> std::process::ExitCode {
    match oilfilm_nodes::shell::player_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("oilfilm-player: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
