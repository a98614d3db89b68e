//! The `cqnet` program with this crate's parts: it serves as the launcher
//! and as every actor of a run, as `cqnet` does.

fn main() -> std::process::ExitCode {
    toy_protocol::app().main()
}
