//! The `cqnet` program with this crate's parts registered: it serves as
//! the launcher and as every actor of a run, as `cqnet` does.

fn main() -> std::process::ExitCode {
    if let Err(e) = toy_protocol::register() {
        eprintln!("error: {e}");
        return std::process::ExitCode::FAILURE;
    }
    cqnet::app::main()
}
