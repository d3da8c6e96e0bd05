//! A minimal odometry process: publishes poses for one source and prints what comes back. It
//! links `lanealign-client` only, as a real odometry process would.
//!
//! Start a daemon first (README, "The daemon"), then:
//! `cargo run --release -p lanealign-client --example odometry_client -- SOURCE`
//!
//! It drives 500 m east along the x axis of its odometry frame (flu axes, 1 m per pose), so any
//! daemon answers with statuses, and a daemon whose source has lanes along that line corrects.

use std::time::Duration;

use lanealign_client::wire::payload::StatusCode;
use lanealign_client::Connection;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let source = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "lidar".to_string());
    let mut conn = Connection::connect(&source)?;
    println!("session {:016x} on source '{source}'", conn.session());
    for i in 0..500u64 {
        let pose = [
            1.0, 0.0, 0.0, i as f64, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        ];
        conn.publish(i as i64 * 100_000_000, &pose)?;
        match conn.recv(Duration::from_millis(200))? {
            Some(c) if c.seq % 50 == 0 => {
                let status = c.status().map_or("unknown", StatusCode::name);
                println!(
                    "seq {:4}: {status:10} x {:8.2} y {:8.2}  map_from_odom ({:.2} m, {:.2} m, {:.4} rad)",
                    c.seq, c.pose[3], c.pose[7], c.map_from_odom[0], c.map_from_odom[1], c.map_from_odom[2]
                );
            }
            Some(_) => {}
            None => println!(
                "seq {}: no answer (is lanealignd serving source '{source}'?)",
                i + 1
            ),
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    // The daemon forgets the session now rather than after its `session_timeout_s`.
    let closed = conn.close(Duration::from_secs(1))?;
    println!(
        "closed: {} answers came while closing, {} never did",
        closed.answers.len(),
        closed.unanswered.len()
    );
    Ok(())
}
