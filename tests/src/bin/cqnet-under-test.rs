//! The `cqnet` program, built inside this package so that its integration
//! tests can run it (`CARGO_BIN_EXE_*` only names a package's own binaries).

fn main() -> std::process::ExitCode {
    launch::app::main()
}
