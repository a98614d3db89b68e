//! The `cqnet` command: the runtime, the experiments and the tools around
//! them (the live view's web server, the fuzzer, the soak) behind one
//! command line. A library too, so that a user's own binary, with parts of
//! its own, can serve as launcher and actor ([`App`]).

pub mod app;
pub mod cli;
pub mod fuzz;
pub mod soak;
pub mod view;

pub use app::App;
