//! A minimal odometry process: publishes poses for one source and prints what comes back.
//!
//! Start a daemon first (for example the one `lanealign demo` shows how to configure), then:
//! `cargo run --release -p lanealign-client --example odometry_client -- SOURCE`
//!
//! It drives the synthetic town's route (flu axes), so a daemon whose source uses `frame = "flu"`
//! and the town's tile answers with corrections; any daemon answers with statuses.

use std::time::Duration;

use lanealign_client::connection::{monotonic_ns, Connection};
use lanealign_client::synthetic;
use lanealign_client::wire::{pose_to_wire, OdomPose, WireStatus};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let source = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "lidar".to_string());
    let conn = Connection::connect(&source)?;
    let (_, odometry) = synthetic::drive(1, 1);
    for (i, p) in odometry.iter().take(500).enumerate() {
        let pose = pose_to_wire(p);
        conn.publish(&OdomPose {
            seq: i as u64 + 1,
            stamp_ns: i as i64 * 100_000_000,
            sent_mono_ns: monotonic_ns(),
            pose,
        })?;
        match conn.recv(Duration::from_millis(200))? {
            Some(c) => {
                let status = WireStatus::from_code(c.status).map_or("unknown", WireStatus::name);
                if c.seq % 50 == 0 {
                    println!("seq {:4}: {status:10} x {:8.2} y {:8.2}  map_from_odom ({:.2} m, {:.2} m, {:.4} rad)",
                        c.seq, c.pose[3], c.pose[7], c.map_from_odom[0], c.map_from_odom[1], c.map_from_odom[2]);
                }
            }
            None => println!(
                "seq {}: no answer (is lanealignd serving source '{source}'?)",
                i + 1
            ),
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}
