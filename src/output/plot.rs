//! `star eval --plot`: one PNG of an estimated trajectory against the
//! truth, drawn with `plotters` into an RGB buffer and written with
//! `image`.
//!
//! Takes the two trajectories (`world_from_camera`, TUM), the association
//! tolerance and the events to mark (from a flight log, or inferred from
//! gaps in the estimate, [`gap_events`]); gives out the picture: on the
//! left the top-down (x/y) trajectory against the truth, on the right the
//! translation and rotation error over time, with lost, relocalization and
//! resume events marked. Text comes from the DejaVu Sans subset embedded in
//! the binary (`assets/fonts`), so no system font is needed.

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;

use crate::dataset::Trajectory;
use crate::eval::associate;

use super::frames_log::LogEvent;

/// The font, embedded: printable ASCII and a few symbols of DejaVu Sans.
const FONT_TTF: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-subset.ttf");
/// The family name the plots ask for.
pub(super) const FONT: &str = "sans-serif";

/// Smallest and largest picture, pixels.
pub const MIN_SIZE_PX: (u32, u32) = (400, 300);
/// See [`MIN_SIZE_PX`].
pub const MAX_SIZE_PX: (u32, u32) = (8000, 8000);

/// Errors drawing the plot.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The requested size is outside [`MIN_SIZE_PX`]..=[`MAX_SIZE_PX`].
    #[error("plot size {width}x{height} is outside 400x300..=8000x8000")]
    Size {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
    },
    /// No estimate pose has a ground-truth pose within the tolerance.
    #[error("no estimate pose is within {max_dt_s} s of a ground-truth pose: nothing to plot")]
    NoOverlap {
        /// The association tolerance, s.
        max_dt_s: f64,
    },
    /// The embedded font could not be loaded.
    #[error("the embedded plot font is invalid")]
    Font,
    /// plotters failed.
    #[error("drawing the plot: {0}")]
    Draw(String),
    /// The PNG could not be written.
    #[error(transparent)]
    Write(#[from] crate::dataset::DatasetError),
}

/// What to draw.
#[derive(Debug, Clone, Copy)]
pub struct PlotInput<'a> {
    /// Ground truth.
    pub ground_truth: &'a Trajectory,
    /// The estimate.
    pub estimate: &'a Trajectory,
    /// Association tolerance, s.
    pub max_dt_s: f64,
    /// Events to mark.
    pub events: &'a [LogEvent],
    /// Where the events came from, for the legend ("flight log", "gaps").
    pub events_from: &'a str,
}

/// Events inferred from gaps in an estimate: a gap longer than three
/// median frame intervals (and 50 ms) is a loss at the first missing frame
/// and a resume at the next pose.
pub fn gap_events(estimate: &Trajectory) -> Vec<LogEvent> {
    let stamps = &estimate.stamps_s;
    let mut dts: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    if dts.is_empty() {
        return Vec::new();
    }
    let mid = dts.len() / 2;
    let median = *dts.select_nth_unstable_by(mid, f64::total_cmp).1;
    let gap = (3.0 * median).max(0.05);
    let mut events = Vec::new();
    for w in stamps.windows(2) {
        if w[1] - w[0] > gap {
            events.push(LogEvent::Lost {
                stamp_s: w[0] + median,
            });
            events.push(LogEvent::Resumed { stamp_s: w[1] });
        }
    }
    events
}

pub(super) fn register_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, FONT_TTF).is_ok());
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// One matched pose: time since the start, the positions, the errors.
struct Matched {
    t_s: f64,
    translation_cm: f64,
    rotation_deg: f64,
}

/// Draws the plot into `path` at `width` x `height` pixels.
pub fn plot_png(
    input: &PlotInput<'_>,
    path: &Path,
    (width, height): (u32, u32),
) -> Result<(), PlotError> {
    if !(MIN_SIZE_PX.0..=MAX_SIZE_PX.0).contains(&width)
        || !(MIN_SIZE_PX.1..=MAX_SIZE_PX.1).contains(&height)
    {
        return Err(PlotError::Size { width, height });
    }
    register_font()?;
    let (gt, est) = (input.ground_truth, input.estimate);
    let pairs = associate(gt, est, input.max_dt_s);
    if pairs.is_empty() {
        return Err(PlotError::NoOverlap {
            max_dt_s: input.max_dt_s,
        });
    }
    let t0_s = gt
        .stamps_s
        .first()
        .copied()
        .unwrap_or(0.0)
        .min(est.stamps_s[0]);
    let matched: Vec<Matched> = pairs
        .iter()
        .map(|&(i, j)| {
            let error = gt.poses[j].inverse() * est.poses[i];
            Matched {
                t_s: est.stamps_s[i] - t0_s,
                translation_cm: error.translation.vector.norm() * 100.0,
                rotation_deg: error.rotation.angle().to_degrees(),
            }
        })
        .collect();
    let mut rgb = vec![255u8; width as usize * height as usize * 3];
    draw(input, &matched, t0_s, &mut rgb, (width, height))
        .map_err(|e| PlotError::Draw(e.to_string()))?;
    let image = image::RgbImage::from_raw(width, height, rgb)
        .ok_or_else(|| PlotError::Draw("the picture buffer has the wrong size".into()))?;
    write_png(path, &image)?;
    Ok(())
}

/// Writes the plot with the best PNG compression (flat colors compress
/// well: a 1600x900 plot is about 100 KB).
pub(super) fn write_png(
    path: &Path,
    image: &image::RgbImage,
) -> Result<(), crate::dataset::DatasetError> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let encode_err = |message: String| crate::dataset::DatasetError::Encode {
        path: path.to_owned(),
        message,
    };
    let file =
        std::fs::File::create(path).map_err(|e| crate::dataset::DatasetError::io(path, e))?;
    PngEncoder::new_with_quality(
        std::io::BufWriter::new(file),
        CompressionType::Best,
        FilterType::Adaptive,
    )
    .write_image(
        image.as_raw(),
        image.width(),
        image.height(),
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| encode_err(e.to_string()))
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

const GT_COLOR: RGBColor = RGBColor(180, 180, 180);
const EST_COLOR: RGBColor = RGBColor(214, 39, 40);
const ROT_COLOR: RGBColor = RGBColor(31, 119, 180);
const LOST_COLOR: RGBColor = RGBColor(255, 127, 14);
const RELOC_COLOR: RGBColor = RGBColor(44, 160, 44);
const RESUME_COLOR: RGBColor = RGBColor(148, 103, 189);

fn event_style(event: &LogEvent) -> (RGBColor, &'static str) {
    match event {
        LogEvent::Lost { .. } => (LOST_COLOR, "lost"),
        LogEvent::Relocalized { .. } => (RELOC_COLOR, "relocalized"),
        LogEvent::Resumed { .. } => (RESUME_COLOR, "resumed"),
    }
}

fn draw(
    input: &PlotInput<'_>,
    matched: &[Matched],
    t0_s: f64,
    rgb: &mut [u8],
    size: (u32, u32),
) -> DrawResult {
    let root = BitMapBackend::with_buffer(rgb, size).into_drawing_area();
    root.fill(&WHITE)?;
    let text = |px: u32| (FONT, px).into_font();
    let font_px = (size.1 / 45).clamp(12, 40);
    let (left, right) = root.split_horizontally(size.0 / 2);
    let (top, bottom) = right.split_vertically(size.1 / 2);
    draw_top_down(input, &left, font_px, &text)?;
    let end_s = matched
        .last()
        .map_or(1.0, |m| m.t_s)
        .max(input.ground_truth.stamps_s.last().map_or(0.0, |t| t - t0_s));
    let series = |m: &Matched| m.translation_cm;
    draw_error(
        input,
        matched,
        t0_s,
        end_s,
        &top,
        ("translation error", "cm", EST_COLOR),
        series,
        font_px,
        &text,
    )?;
    draw_error(
        input,
        matched,
        t0_s,
        end_s,
        &bottom,
        ("rotation error", "deg", ROT_COLOR),
        |m| m.rotation_deg,
        font_px,
        &text,
    )?;
    root.present()?;
    Ok(())
}

fn draw_top_down<DB: DrawingBackend>(
    input: &PlotInput<'_>,
    area: &DrawingArea<DB, plotters::coord::Shift>,
    font_px: u32,
    text: &dyn Fn(u32) -> FontDesc<'static>,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let (gt, est) = (input.ground_truth, input.estimate);
    let xy = |t: &Trajectory| -> Vec<(f64, f64)> {
        t.poses
            .iter()
            .map(|p| (p.translation.vector.x, p.translation.vector.y))
            .collect()
    };
    let (gt_xy, est_xy) = (xy(gt), xy(est));
    let all = gt_xy.iter().chain(&est_xy);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    // Same meters per pixel on both axes, with a margin.
    let (w_px, h_px) = area.dim_in_pixel();
    let (plot_w, plot_h) = (
        (w_px as f64 - 90.0).max(50.0),
        (h_px as f64 - 110.0).max(50.0),
    );
    let span = ((x1 - x0) / plot_w).max((y1 - y0) / plot_h).max(1e-3) * 1.1;
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let (hx, hy) = (span * plot_w / 2.0, span * plot_h / 2.0);
    let mut chart = ChartBuilder::on(area)
        .caption("top-down trajectory (world x/y)", text(font_px + 4))
        .margin(12)
        .x_label_area_size(font_px * 3)
        .y_label_area_size(font_px * 4)
        .build_cartesian_2d((cx - hx)..(cx + hx), (cy - hy)..(cy + hy))?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .label_style(text(font_px))
        .axis_desc_style(text(font_px))
        .light_line_style(TRANSPARENT)
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            gt_xy.iter().copied(),
            GT_COLOR.stroke_width(6),
        ))?
        .label("ground truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], GT_COLOR.stroke_width(6)));
    // The estimate as dots: a gap shows as a gap.
    chart
        .draw_series(
            est_xy
                .iter()
                .map(|&p| Circle::new(p, 1, EST_COLOR.filled())),
        )?
        .label("estimate")
        .legend(|(x, y)| Circle::new((x + 10, y), 3, EST_COLOR.filled()));
    // Events at the ground-truth position nearest in time.
    for event in input.events {
        let (color, _) = event_style(event);
        let t = event.stamp_s();
        let k = gt
            .stamps_s
            .partition_point(|&s| s < t)
            .min(gt.len().saturating_sub(1));
        if let Some(&p) = gt_xy.get(k) {
            chart.draw_series(std::iter::once(Cross::new(p, 7, color.stroke_width(3))))?;
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(text(font_px))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn draw_error<DB: DrawingBackend>(
    input: &PlotInput<'_>,
    matched: &[Matched],
    t0_s: f64,
    end_s: f64,
    area: &DrawingArea<DB, plotters::coord::Shift>,
    (name, unit, color): (&str, &str, RGBColor),
    value: impl Fn(&Matched) -> f64,
    font_px: u32,
    text: &dyn Fn(u32) -> FontDesc<'static>,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let max = matched.iter().map(&value).fold(0.0f64, f64::max);
    let top = if max > 0.0 { max * 1.15 } else { 1.0 };
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{name} ({unit}) over time"), text(font_px + 4))
        .margin(12)
        .x_label_area_size(font_px * 3)
        .y_label_area_size(font_px * 4)
        .build_cartesian_2d(0.0..end_s.max(1e-3), 0.0..top)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc(unit)
        .label_style(text(font_px))
        .axis_desc_style(text(font_px))
        .light_line_style(TRANSPARENT)
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()?;
    // Segments split where the estimate has a gap (lost frames).
    let gap_s = median_step_s(matched) * 3.0;
    let mut segment: Vec<(f64, f64)> = Vec::new();
    let mut first = true;
    let flush = |segment: &mut Vec<(f64, f64)>,
                 first: &mut bool,
                 chart: &mut ChartContext<'_, DB, _>|
     -> DrawResult {
        if segment.is_empty() {
            return Ok(());
        }
        let drawn = chart.draw_series(LineSeries::new(segment.drain(..), color.stroke_width(2)))?;
        if std::mem::take(first) {
            drawn
                .label(format!("{name} ({} matched poses)", matched.len()))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        Ok(())
    };
    let mut last_t: Option<f64> = None;
    for m in matched {
        if last_t.is_some_and(|t| m.t_s - t > gap_s) {
            flush(&mut segment, &mut first, &mut chart)?;
        }
        segment.push((m.t_s, value(m)));
        last_t = Some(m.t_s);
    }
    flush(&mut segment, &mut first, &mut chart)?;
    let mut labelled = [false; 3];
    for event in input.events {
        let (ecolor, label) = event_style(event);
        let t = event.stamp_s() - t0_s;
        let drawn = chart.draw_series(std::iter::once(PathElement::new(
            vec![(t, 0.0), (t, top)],
            ecolor.stroke_width(2),
        )))?;
        let slot = match event {
            LogEvent::Lost { .. } => 0,
            LogEvent::Relocalized { .. } => 1,
            LogEvent::Resumed { .. } => 2,
        };
        if !std::mem::replace(&mut labelled[slot], true) {
            drawn
                .label(format!("{label} ({})", input.events_from))
                .legend(move |(x, y)| {
                    PathElement::new(
                        vec![(x + 10, y - 6), (x + 10, y + 6)],
                        ecolor.stroke_width(2),
                    )
                });
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(text(font_px))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn median_step_s(matched: &[Matched]) -> f64 {
    let mut steps: Vec<f64> = matched.windows(2).map(|w| w[1].t_s - w[0].t_s).collect();
    if steps.is_empty() {
        return f64::INFINITY;
    }
    let mid = steps.len() / 2;
    (*steps.select_nth_unstable_by(mid, f64::total_cmp).1).max(1e-6)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;

    fn circle(n: usize, skip: std::ops::Range<usize>, wobble_m: f64) -> Trajectory {
        let mut t = Trajectory::default();
        for i in (0..n).filter(|i| !skip.contains(i)) {
            let a = i as f64 * 0.05;
            t.push(
                100.0 + i as f64 * 0.02,
                Pose::translation(a.cos() + wobble_m * (i as f64).sin(), a.sin(), 1.0),
            );
        }
        t
    }

    #[test]
    fn gaps_become_lost_and_resumed_events() {
        let est = circle(100, 40..60, 0.0);
        let events = gap_events(&est);
        assert_eq!(events.len(), 2);
        assert!(matches!(events[0], LogEvent::Lost { stamp_s } if (stamp_s - 100.80).abs() < 1e-9));
        assert!(
            matches!(events[1], LogEvent::Resumed { stamp_s } if (stamp_s - 101.20).abs() < 1e-9)
        );
        assert!(gap_events(&circle(100, 0..0, 0.0)).is_empty());
    }

    #[test]
    fn draws_a_picture_of_the_requested_size_with_content() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("plot.png");
        let (gt, est) = (circle(100, 0..0, 0.0), circle(100, 40..60, 0.02));
        let events = gap_events(&est);
        let input = PlotInput {
            ground_truth: &gt,
            estimate: &est,
            max_dt_s: 0.005,
            events: &events,
            events_from: "gaps",
        };
        plot_png(&input, &path, (640, 400)).expect("plot");
        let image = image::open(&path).expect("decode").to_rgb8();
        assert_eq!(image.dimensions(), (640, 400));
        let colored = image.pixels().filter(|p| p.0 == [214, 39, 40]).count();
        assert!(colored > 100, "estimate color pixels: {colored}");
        assert!(matches!(
            plot_png(&input, &path, (100, 100)),
            Err(PlotError::Size { .. })
        ));
    }
}
