//! SVG plots of a run (plotters): trajectories over the lanes in the map plane, and the position
//! error over the distance driven.

use std::path::{Path, PathBuf};

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

/// A plot that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// Drawing or writing failed.
    #[error("plotting {path}: {message}")]
    Draw {
        /// The SVG file.
        path: PathBuf,
        /// What plotters said.
        message: String,
    },
    /// Nothing to plot.
    #[error("plotting {0}: no points")]
    Empty(PathBuf),
}

/// One polyline of a plot (metres, map plane) with its legend name and colour.
pub struct Track<'a> {
    /// Legend name.
    pub name: &'a str,
    /// The points.
    pub points: &'a [[f64; 2]],
    /// Line colour.
    pub color: RGBColor,
}

/// Raw odometry.
pub const RAW: RGBColor = RGBColor(31, 119, 180);
/// Corrected output.
pub const CORRECTED: RGBColor = RGBColor(214, 39, 40);
/// Ground truth.
pub const GROUND_TRUTH: RGBColor = RGBColor(30, 30, 30);
const LANES: RGBColor = RGBColor(200, 200, 200);
const MARKS: RGBColor = RGBColor(255, 140, 0);

fn draw_error(path: &Path) -> impl Fn(&dyn std::fmt::Display) -> PlotError + '_ {
    move |e| PlotError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Draws the legend in the upper left corner and writes the file.
fn finish<'a, 'b: 'a>(
    mut chart: ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    root: DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    path: &Path,
) -> Result<(), PlotError> {
    let fail = draw_error(path);
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()
        .map_err(|e| fail(&e))?;
    root.present().map_err(|e| fail(&e))
}

/// A square view holding every point of `tracks`, with a 5 % margin (metres).
fn square_view(tracks: &[Track]) -> Option<([f64; 2], [f64; 2])> {
    let mut points = tracks.iter().flat_map(|t| t.points.iter());
    let first = *points.next()?;
    let (mut lo, mut hi) = (first, first);
    for p in points {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    let half = ((hi[0] - lo[0]).max(hi[1] - lo[1]) * 0.55).max(10.0);
    let mid = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    Some((
        [mid[0] - half, mid[0] + half],
        [mid[1] - half, mid[1] + half],
    ))
}

/// The tracks over the lanes (grey), with `marks` (a legend name and points) drawn as dots:
/// metres in the map plane, equal scale on both axes.
pub fn trajectories(
    path: &Path,
    title: &str,
    lanes: &[&[[f64; 2]]],
    tracks: &[Track],
    marks: (&str, &[[f64; 2]]),
) -> Result<(), PlotError> {
    let fail = draw_error(path);
    let (x, y) = square_view(tracks).ok_or_else(|| PlotError::Empty(path.to_path_buf()))?;
    let root = SVGBackend::new(path, (1000, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d(x[0]..x[1], y[0]..y[1])
        .map_err(|e| fail(&e))?;
    chart
        .configure_mesh()
        .x_desc("x, map plane (m)")
        .y_desc("y, map plane (m)")
        .light_line_style(WHITE)
        .draw()
        .map_err(|e| fail(&e))?;
    let inside = |p: &[f64; 2]| {
        p[0] >= x[0] - 100.0 && p[0] <= x[1] + 100.0 && p[1] >= y[0] - 100.0 && p[1] <= y[1] + 100.0
    };
    chart
        .draw_series(lanes.iter().filter(|l| l.iter().any(inside)).map(|l| {
            PathElement::new(
                l.iter().map(|p| (p[0], p[1])).collect::<Vec<_>>(),
                LANES.stroke_width(3),
            )
        }))
        .map_err(|e| fail(&e))?
        .label("lanes (OpenStreetMap)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], LANES.stroke_width(3)));
    for t in tracks {
        let color = t.color;
        chart
            .draw_series(LineSeries::new(
                t.points.iter().map(|p| (p[0], p[1])),
                color.stroke_width(2),
            ))
            .map_err(|e| fail(&e))?
            .label(t.name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
    }
    let (mark_name, mark_points) = marks;
    chart
        .draw_series(
            mark_points
                .iter()
                .map(|p| Circle::new((p[0], p[1]), 3, MARKS.filled())),
        )
        .map_err(|e| fail(&e))?
        .label(mark_name)
        .legend(|(x, y)| Circle::new((x + 10, y), 3, MARKS.filled()));
    finish(chart, root, path)
}

/// Position error (metres) over distance driven (metres), one line per series.
pub fn error_over_distance(
    path: &Path,
    title: &str,
    distance_m: &[f64],
    series: &[(&str, &[f64], RGBColor)],
) -> Result<(), PlotError> {
    lines(
        path,
        title,
        ("distance driven (m)", "position error, 2D (m)"),
        distance_m,
        series,
    )
}

/// Colours for series without a meaning of their own, in order.
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// Lines over a shared x axis from 0, one per series (`axes`: the x and y descriptions, with
/// units).
pub fn lines(
    path: &Path,
    title: &str,
    axes: (&str, &str),
    x: &[f64],
    series: &[(&str, &[f64], RGBColor)],
) -> Result<(), PlotError> {
    let fail = draw_error(path);
    let distance_m = x;
    let x_max = distance_m.iter().copied().fold(0.0f64, f64::max).max(1.0);
    let y_max = series
        .iter()
        .flat_map(|s| s.1.iter().copied())
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        .max(0.1)
        * 1.05;
    let root = SVGBackend::new(path, (1200, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..x_max, 0.0..y_max)
        .map_err(|e| fail(&e))?;
    chart
        .configure_mesh()
        .x_desc(axes.0)
        .y_desc(axes.1)
        .draw()
        .map_err(|e| fail(&e))?;
    for &(name, errors, color) in series {
        chart
            .draw_series(LineSeries::new(
                distance_m.iter().copied().zip(errors.iter().copied()),
                color.stroke_width(2),
            ))
            .map_err(|e| fail(&e))?
            .label(name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
    }
    finish(chart, root, path)
}
