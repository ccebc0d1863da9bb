//! `cell`: the operator's command line for the grasping cell.

fn main() -> std::process::ExitCode {
    graspcell::cli::main()
}
