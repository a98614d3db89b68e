//! The live view's web page: served during a run (`cqnet run --view`) or
//! replayed from a finished run's files (`cqnet view OUT_DIR`). The events
//! it draws are the runtime's ([`launch::feed`]).

pub mod replay;
pub mod server;
