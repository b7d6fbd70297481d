//! `host-sim`: the command line of the simulator (`cli/`); the work is the library's.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
