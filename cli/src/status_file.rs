//! The status CSV of `lanealign correct --status` and `lanealign replay --status`: one row per
//! pose with what the corrector did, `map_from_odom`, and the covariance of the corrected pose;
//! and reading the covariances back for `lanealign eval --status`.
//!
//! Columns: `index,status,reason,residual_m,match_ratio,window_len,map_from_odom_x,
//! map_from_odom_y,map_from_odom_yaw,applied_directions,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,
//! cov_yawyaw,anchor_yaw,odometry_scale,odometry_scale_sd`. The covariance is in the map plane
//! (metres^2, metre-radians, radians^2); `anchor_yaw` (radians) is the rotation of the anchor's
//! placement, which turns the source's planar odometry frame into the map plane before any
//! correction: the error of a corrected pose in the map plane is that rotation applied to its
//! error in the odometry frame. `odometry_scale` is what the odometry's steps are multiplied by
//! after the pose (1 where the scale is not estimated), `odometry_scale_sd` its standard
//! deviation (0 there).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{bail, Context};
use lanealign_core::confidence::{position_covariance_in, Covariance};
use lanealign_core::geo::is_anchor_yaw_rad;
use lanealign_core::input::{Lines, Outputs};
use lanealign_core::number_text::push_separated;
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::CorrectedPose;
use lanealign_core::trajectory::{self, Format, Trajectory};
use lanealign_wire::payload::upper_triangle;

/// The header line of the status CSV.
pub const HEADER: &str = "index,status,reason,residual_m,match_ratio,window_len,map_from_odom_x,map_from_odom_y,map_from_odom_yaw,applied_directions,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw,anchor_yaw,odometry_scale,odometry_scale_sd";

/// One row of the status CSV.
#[derive(Clone, Copy, Debug)]
pub struct Row<'a> {
    /// The status name.
    pub status: &'a str,
    /// The reject reason name, empty when there is none.
    pub reason: &'a str,
    /// Mean ICP residual (metres); NaN when no matching ran.
    pub residual_m: f64,
    /// Matched fraction of the window; NaN when no matching ran.
    pub match_ratio: f64,
    /// Poses in the window.
    pub window_len: usize,
    /// The exact correction (odometry plane to map plane) as x (metres), y (metres), yaw
    /// (radians): the wire's numbers as they are (a yaw through a rotation matrix and back may
    /// change in its last bit).
    pub map_from_odom: [f64; 3],
    /// Directions of the correction applied on an accepted step (0 otherwise).
    pub applied_directions: u8,
    /// Covariance of the corrected pose (map plane).
    pub covariance: Covariance,
    /// The rotation of the source's anchor (radians).
    pub anchor_yaw: f64,
    /// What the odometry's steps are multiplied by after the pose (a ratio).
    pub odometry_scale: f64,
    /// The standard deviation of `odometry_scale` (a ratio).
    pub odometry_scale_sd: f64,
}

/// The status CSV of `rows`, header first, rows numbered from 0.
pub fn format<'a>(rows: impl ExactSizeIterator<Item = Row<'a>>) -> String {
    let mut out = String::with_capacity((rows.len() + 1) * 250);
    out.push_str(HEADER);
    out.push('\n');
    for (index, row) in rows.enumerate() {
        push_row(&mut out, index, &row);
    }
    out
}

fn push_row(out: &mut String, index: usize, row: &Row<'_>) {
    let _ = write!(out, "{index},{},{},", row.status, row.reason);
    push_separated(out, &[row.residual_m, row.match_ratio], ',');
    let _ = write!(out, ",{},", row.window_len);
    push_separated(out, &row.map_from_odom, ',');
    let _ = write!(out, ",{},", row.applied_directions);
    push_separated(out, &upper_triangle(&row.covariance), ',');
    out.push(',');
    push_separated(
        out,
        &[row.anchor_yaw, row.odometry_scale, row.odometry_scale_sd],
        ',',
    );
    out.push('\n');
}

/// The status CSV of a run corrected offline (`lanealign correct`), whose source the anchor
/// placed by `anchored_from_odom`.
pub fn of_run(run: &[CorrectedPose], anchored_from_odom: &Se2) -> String {
    let anchor_yaw = anchored_from_odom.yaw();
    format(run.iter().map(|c| {
        let s = &c.status;
        Row {
            status: s.name(),
            reason: s.reason().map_or("", |r| r.name()),
            residual_m: s.residual_m().unwrap_or(f64::NAN),
            match_ratio: s.match_ratio().unwrap_or(f64::NAN),
            window_len: s.window_len(),
            map_from_odom: {
                let [x, y] = c.map_from_odom.translation();
                [x, y, c.map_from_odom.yaw()]
            },
            applied_directions: s.applied_directions(),
            covariance: c.covariance,
            anchor_yaw,
            odometry_scale: c.odometry_scale,
            odometry_scale_sd: c.odometry_scale_sd,
        }
    }))
}

/// The line `correct` and `replay` end with for a source whose session estimates its odometry's
/// scale: the last finite estimate among `estimates` (`(odometry_scale, odometry_scale_sd)` per
/// pose, oldest first, as the status CSV's columns), when it is an estimate (its sd above 0);
/// `None` otherwise.
pub fn scale_summary(estimates: impl DoubleEndedIterator<Item = (f64, f64)>) -> Option<String> {
    let (scale, _) = estimates
        .rev()
        .find(|(scale, _)| scale.is_finite())
        .filter(|(_, sd)| *sd > 0.0)?;
    Some(format!(
        "odometry scale: steps multiplied by {scale:.4} at the end (estimated from the lanes)"
    ))
}

/// Writes a corrected trajectory to `output` and, when asked, its status CSV to `status`: both
/// appear only when both were written.
pub fn write_run(
    output: &Path,
    trajectory: &Trajectory,
    format: Format,
    status: Option<(&Path, &str)>,
) -> anyhow::Result<()> {
    let mut outputs = Outputs::default();
    outputs.stage(
        output,
        trajectory::format_text(trajectory, format, output)?.as_bytes(),
    )?;
    if let Some((path, csv)) = status {
        outputs.stage(path, csv.as_bytes())?;
    }
    outputs.commit()?;
    Ok(())
}

/// The position block of a map-plane `covariance` (metres^2), turned into the planar odometry
/// frame of a source anchored with yaw `anchor_yaw` (radians, the status CSV's and the wire's
/// `anchor_yaw`): what errors in the odometry frame are compared with.
pub fn position_covariance_in_odom(anchor_yaw: f64, covariance: &Covariance) -> [[f64; 2]; 2] {
    position_covariance_in(&Se2::new(-anchor_yaw, 0.0, 0.0), covariance)
}

/// The position covariances of a status CSV, turned into the source's planar odometry frame
/// (metres^2), one per row in order.
pub fn read_position_covariances(path: &Path) -> anyhow::Result<Vec<[[f64; 2]; 2]>> {
    let mut lines = Lines::open(path)?;
    let header = match lines.next() {
        Some(line) => line?.1,
        None => bail!("{}: empty, not a status CSV", path.display()),
    };
    let names: Vec<&str> = header.split(',').collect();
    let column = |name: &str| {
        names.iter().position(|&n| n == name).with_context(|| {
            format!(
                "{}: no column {name}: not a status CSV of this version of lanealign",
                path.display()
            )
        })
    };
    let columns = [
        column("cov_xx")?,
        column("cov_xy")?,
        column("cov_yy")?,
        column("anchor_yaw")?,
    ];
    let mut out = Vec::new();
    for line in lines {
        let (number, text) = line?;
        let fields: Vec<&str> = text.split(',').collect();
        let value = |k: usize| -> anyhow::Result<f64> {
            let field = fields
                .get(columns[k])
                .with_context(|| format!("{}:{number}: too few columns", path.display()))?;
            field.parse().with_context(|| {
                format!(
                    "{}:{number}: {} is not a number",
                    path.display(),
                    lanealign_core::input::quote(field)
                )
            })
        };
        let (xx, xy, yy, yaw) = (value(0)?, value(1)?, value(2)?, value(3)?);
        if !is_anchor_yaw_rad(yaw) {
            bail!(
                "{}:{number}: anchor_yaw {yaw:?} is not an angle in [-2 pi, 2 pi] radians",
                path.display()
            );
        }
        let covariance = [[xx, xy, 0.0], [xy, yy, 0.0], [0.0, 0.0, 0.0]];
        out.push(position_covariance_in_odom(yaw, &covariance));
    }
    Ok(out)
}
