//! `cqnet`: run a decentralized sensor network and compute its CQ/dPCRLB.

fn main() -> std::process::ExitCode {
    cqnet::app::main()
}
