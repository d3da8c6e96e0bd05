//! The contract between odometry processes and `lanealignd`: what travels over shared memory
//! ([`payload`]), under which service names and with which limits ([`service`]), and the clock
//! both sides time it with ([`clock`]), how either side waits for the other ([`wait`]), and the
//! room both need in shared memory ([`shm`]). An odometry process links this crate and
//! `lanealign-client`, nothing else of lanealign; processes in other languages follow
//! `docs/wire.md`, which this crate's tests pin.
//!
//! ```no_run
//! use lanealign_wire::service::{Ipc, Namespace, PoseServices};
//!
//! let node = Namespace::default().node::<Ipc>()?;
//! let services = PoseServices::open(&node, &"lidar".parse()?)?;
//! let publisher = services.publisher()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod clock;
pub mod payload;
pub mod service;
pub mod shm;
pub mod wait;
