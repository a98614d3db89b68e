//! The `cqnet` program, built inside this package so that its integration
//! tests can run it (`CARGO_BIN_EXE_*` only names a package's own binaries):
//! the two lines a user's crate needs to do the same.

fn main() -> std::process::ExitCode {
    cqnet_testkit::App::new().main()
}
