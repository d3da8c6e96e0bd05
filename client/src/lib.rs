//! What an odometry process links to talk to `lanealignd`: [`Connection`] connects to one
//! source, publishes poses in a session of its own and receives that session's corrections,
//! each exactly once, across daemon restarts. It depends on `lanealign-wire` and iceoryx2 only.
//!
//! ```no_run
//! use std::time::Duration;
//! use lanealign_client::Connection;
//!
//! let mut conn = Connection::connect("lidar")?;
//! let identity = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
//! conn.publish(0, &identity)?;
//! if let Some(corrected) = conn.recv(Duration::from_millis(100))? {
//!     println!("seq {} corrected to {:?}", corrected.seq, corrected.pose);
//! }
//! // Done: the answers still in flight, then the daemon forgets the session at once.
//! let closed = conn.close(Duration::from_secs(1))?;
//! println!("{} more answers, {} unanswered", closed.answers.len(), closed.unanswered.len());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod connection;

pub use connection::{
    AnswerWaiter, CloseError, Closed, ConnectError, Connection, PublishError, ReceiveError,
};
pub use lanealign_wire as wire;
