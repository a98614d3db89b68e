//! `cqnet`: run a decentralized sensor network and compute its CQ/dPCRLB.

fn main() -> std::process::ExitCode {
    cqnet::App::new().main()
}
