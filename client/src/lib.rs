//! lanealign client side: the wire types and connection odometry processes use to talk to
//! `lanealignd`, and the building blocks of the `lanealign` tools (map loading, replay, the
//! synthetic town, running the daemon).
//!
//! See [`connection::Connection`] for the runnable example.

pub mod connection;
pub mod daemon_process;
pub mod kitti;
pub mod maps;
pub mod replay;
pub mod synthetic;
pub mod wire;
