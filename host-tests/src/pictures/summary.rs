//! The picture of a whole run (`flatland detect --summary FILE.png`), drawn
//! with plotters: over the frames, the alarm against truth.toml's, the
//! nearest distance against truth's, the seed's statistics (sad, count50),
//! and the motion and attitude estimated since the reference frame. A frame
//! not judged is a grey alarm bar and has no values in the other panels.

use crate::evaluate::{is_grace, score};
use crate::pictures::raster::{RgbImage, FONT};
use crate::recording::Truth;
use flatland_core::geometry::Aoi;
use flatland_core::report::{FrameReport, ANGLE_SCALE, MOTION_SCALE};
use plotters::backend::BitMapBackend;
use plotters::chart::{ChartBuilder, ChartContext};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::drawing::DrawingArea;
use plotters::element::{Circle, Cross, PathElement, Rectangle};
use plotters::series::LineSeries;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{Color, IntoFont, RGBColor, ShapeStyle, BLACK, WHITE};

/// The summary picture's size, px.
pub const SUMMARY_SIZE: (usize, usize) = (1100, 1400);

const ALARM: RGBColor = RGBColor(220, 40, 40);
const CLEAR: RGBColor = RGBColor(150, 205, 160);
/// A frame not judged (its alarm is the fail-safe's).
const NOT_JUDGED: RGBColor = RGBColor(150, 150, 150);
const TRUTH: RGBColor = RGBColor(20, 20, 20);
const AOI: RGBColor = RGBColor(40, 170, 60);
const BLUE: RGBColor = RGBColor(30, 100, 220);
const ORANGE: RGBColor = RGBColor(240, 140, 0);
const PURPLE: RGBColor = RGBColor(150, 60, 190);

type Chart<'a, 'b> = ChartContext<'a, BitMapBackend<'b>, plotters::coord::cartesian::Cartesian2d<RangedCoordf64, RangedCoordf64>>;
type Failure = Box<dyn std::error::Error>;

/// The series a panel draws: colour, and one point per frame (None where
/// that frame has no value: lines break there).
struct Series {
    colour: RGBColor,
    points: Vec<(f64, Option<f64>)>,
}

impl Series {
    /// A frame not judged has no value (its fields are the fail-safe's).
    fn new(colour: RGBColor, reports: &[FrameReport], value: impl Fn(&FrameReport) -> Option<f64>) -> Series {
        Series { colour, points: reports.iter().map(|r| (f64::from(r.frame), if r.is_judged() { value(r) } else { None })).collect() }
    }

    /// Runs of consecutive frames that have values.
    fn runs(&self) -> Vec<Vec<(f64, f64)>> {
        let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut previous: Option<f64> = None;
        for &(x, y) in &self.points {
            match y {
                Some(y) => {
                    if previous.is_none_or(|p| x - p > 1.0) || runs.is_empty() {
                        runs.push(Vec::new());
                    }
                    runs.last_mut().expect("pushed").push((x, y));
                    previous = Some(x);
                }
                None => previous = None,
            }
        }
        runs
    }

    fn range(&self) -> Option<(f64, f64)> {
        let values = self.points.iter().filter_map(|p| p.1);
        values.fold(None, |range, v| Some(range.map_or((v, v), |(lo, hi): (f64, f64)| (lo.min(v), hi.max(v)))))
    }
}

/// A y range covering every series (and `include`), padded by 8 %.
fn y_range(series: &[&Series], include: &[f64]) -> std::ops::Range<f64> {
    let mut range = include.iter().fold(None, |range: Option<(f64, f64)>, &v| Some(range.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v)))));
    for s in series {
        if let Some((lo, hi)) = s.range() {
            range = Some(range.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
        }
    }
    let (lo, hi) = range.unwrap_or((0.0, 1.0));
    let pad = ((hi - lo) * 0.08).max(1e-3);
    (lo - pad)..(hi + pad)
}

fn chart<'a, 'b>(area: &'a DrawingArea<BitMapBackend<'b>, Shift>, caption: &str, frames: std::ops::Range<f64>, y: std::ops::Range<f64>, y_desc: &str, decimals: usize) -> Result<Chart<'a, 'b>, Failure> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 17).into_font())
        .margin(6)
        .margin_right(LEGEND_WIDTH)
        .x_label_area_size(34)
        .y_label_area_size(78)
        .build_cartesian_2d(frames, y)?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .x_label_formatter(&|x: &f64| format!("{x:.0}"))
        .y_label_formatter(&|y: &f64| format!("{y:.decimals$}"))
        .y_desc(y_desc)
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    Ok(chart)
}

fn draw_lines<'a, 'b: 'a>(chart: &mut Chart<'a, 'b>, series: &Series) -> Result<(), Failure> {
    let style = ShapeStyle { color: series.colour.to_rgba(), filled: false, stroke_width: 2 };
    let colour = series.colour;
    for run in series.runs() {
        chart.draw_series(LineSeries::new(run.clone(), style))?;
        chart.draw_series(run.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
    }
    Ok(())
}

/// Room right of the plots for their legends, px.
const LEGEND_WIDTH: u32 = 250;

/// A legend in the room right of a panel's plot, `indent` px into it:
/// a line of each colour and its name.
fn draw_legend(area: &DrawingArea<BitMapBackend<'_>, Shift>, indent: i32, entries: &[(&str, RGBColor)]) -> Result<(), Failure> {
    let (width, _) = area.dim_in_pixel();
    let x = width as i32 - LEGEND_WIDTH as i32 + indent;
    for (k, (name, colour)) in entries.iter().enumerate() {
        let y = 40 + 20 * k as i32;
        area.draw(&PathElement::new(vec![(x, y), (x + 22, y)], colour.stroke_width(3)))?;
        area.draw_text(name, &(FONT, 13).into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center)), (x + 30, y))?;
    }
    Ok(())
}

/// Draws the run's summary into a picture of [`SUMMARY_SIZE`].
pub fn summary_picture(name: &str, reports: &[FrameReport], truth: Option<&Truth>, aoi: &Aoi) -> Result<RgbImage, Failure> {
    let (width, height) = SUMMARY_SIZE;
    let mut picture = RgbImage::new(width, height);
    {
        let root = picture.canvas();
        root.fill(&WHITE)?;
        let (title_area, body) = root.split_vertically(54);
        let first = reports.first().map_or(0.0, |r| f64::from(r.frame));
        let last = reports.last().map_or(1.0, |r| f64::from(r.frame));
        let frames = (first - 0.7)..(last + 0.7);
        let judged = reports.iter().filter(|r| r.is_judged()).count();
        let mut title = format!("flatland detect {name}: {judged} frames compared");
        if judged < reports.len() {
            title += &format!(", {} not judged", reports.len() - judged);
        }
        let subtitle = match truth {
            Some(truth) => {
                let (c, _) = score(truth, reports);
                title += &format!(", {} errors outside grace frames", c.errors());
                format!(
                    "truth.toml: {} alarms right, {} missed, {} false, {} clear right; grace frames {} right, {} wrong",
                    c.true_alarm, c.missed, c.false_alarm, c.true_clear, c.grace_right, c.grace_wrong
                )
            }
            None => "no truth.toml: the detector's answers alone".to_string(),
        };
        title_area.draw_text(&title, &(FONT, 21).into_font().color(&BLACK), (16, 8))?;
        title_area.draw_text(&subtitle, &(FONT, 14).into_font().color(&BLACK.mix(0.7)), (16, 34))?;
        let panels = body.split_evenly((5, 1));

        // 1. Alarm against truth: one bar per frame, detected above truth.
        {
            let mut chart = ChartBuilder::on(&panels[0])
                .caption("alarm: detected and truth.toml's (x: an error outside grace frames)", (FONT, 17).into_font())
                .margin(6)
                .margin_right(LEGEND_WIDTH)
                .x_label_area_size(34)
                .y_label_area_size(78)
                .build_cartesian_2d(frames.clone(), 0.0..2.0)?;
            chart
                .configure_mesh()
                .x_desc("frame")
                .x_label_formatter(&|x: &f64| format!("{x:.0}"))
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .light_line_style(WHITE.mix(0.0))
                .y_labels(5)
                .y_label_formatter(&|y: &f64| match (y * 2.0).round() as i32 {
                    3 => "detected".into(),
                    1 if truth.is_some() => "truth".into(),
                    _ => String::new(),
                })
                .draw()?;
            let bar = |frame: f64, row: f64, colour: RGBColor| Rectangle::new([(frame - 0.42, row + 0.12), (frame + 0.42, row + 0.88)], colour.filled());
            let colour = |alarm: bool| if alarm { ALARM } else { CLEAR };
            let detected = |r: &FrameReport| if r.is_judged() { colour(r.alarm) } else { NOT_JUDGED };
            chart.draw_series(reports.iter().map(|r| bar(f64::from(r.frame), 1.0, detected(r))))?;
            if let Some(truth) = truth {
                let compared = truth.pair.iter().filter(|p| reports.iter().any(|r| r.frame == p.frame));
                chart.draw_series(compared.clone().map(|p| bar(f64::from(p.frame), 0.0, colour(p.alarm))))?;
                let grace = compared.filter(|p| is_grace(truth, p.frame)).map(|p| f64::from(p.frame));
                chart.draw_series(grace.map(|f| Rectangle::new([(f - 0.46, 0.06), (f + 0.46, 1.94)], BLACK.stroke_width(2))))?;
                let errors = reports.iter().filter(|r| r.is_judged() && truth.pair(r.frame).is_some_and(|p| p.alarm != r.alarm) && !is_grace(truth, r.frame));
                chart.draw_series(errors.map(|r| Cross::new((f64::from(r.frame), 1.0), 7, BLACK.stroke_width(3))))?;
            }
            let mut legend = vec![("alarm", ALARM), ("clear", CLEAR)];
            if judged < reports.len() {
                legend.push(("not judged (alarm)", NOT_JUDGED));
            }
            if truth.is_some() {
                legend.push(("grace frame (outlined)", BLACK));
            }
            draw_legend(&panels[0], 10, &legend)?;
        }

        // 2. Nearest distance against truth, with the AOI's depth.
        {
            let detected = Series::new(ALARM, reports, |r| r.nearest_mm.map(f64::from));
            let truth_series = truth.map(|t| Series::new(TRUTH, reports, |r| t.pair(r.frame).and_then(|p| p.nearest_mm)));
            let mut all = vec![&detected];
            all.extend(truth_series.as_ref());
            let mut chart = chart(&panels[1], "nearest distance ahead", frames.clone(), y_range(&all, &[aoi.near_mm, aoi.far_mm]), "mm", 0)?;
            let aoi_style = AOI.stroke_width(1);
            for z in [aoi.near_mm, aoi.far_mm] {
                chart.draw_series(LineSeries::new([(frames.start, z), (frames.end, z)], aoi_style))?;
            }
            if let Some(series) = &truth_series {
                draw_lines(&mut chart, series)?;
            }
            draw_lines(&mut chart, &detected)?;
            let mut legend = vec![("nearest_mm", ALARM)];
            if truth.is_some() {
                legend.push(("truth nearest_mm", TRUTH));
            }
            legend.push(("AOI near, far", AOI));
            draw_legend(&panels[1], 10, &legend)?;
        }

        // 3. The seed's statistics: sad (left axis), count50 (right axis).
        {
            let sad = Series::new(BLUE, reports, |r| Some(f64::from(r.sad)));
            let count = Series::new(ORANGE, reports, |r| Some(f64::from(r.count50)));
            let mut chart = ChartBuilder::on(&panels[2])
                .caption("the seed's statistics at the predicted shift", (FONT, 17).into_font())
                .margin(6)
                .margin_right(LEGEND_WIDTH - 70)
                .x_label_area_size(34)
                .y_label_area_size(78)
                .right_y_label_area_size(70)
                .build_cartesian_2d(frames.clone(), y_range(&[&sad], &[0.0]))?
                .set_secondary_coord(frames.clone(), y_range(&[&count], &[0.0]));
            chart
                .configure_mesh()
                .x_desc("frame")
                .x_label_formatter(&|x: &f64| format!("{x:.0}"))
                .y_label_formatter(&|y: &f64| format!("{y:.0}"))
                .y_desc("sad")
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .light_line_style(WHITE.mix(0.0))
                .draw()?;
            chart.configure_secondary_axes().y_desc("count50").y_label_formatter(&|y: &f64| format!("{y:.0}")).label_style((FONT, 13)).axis_desc_style((FONT, 14)).draw()?;
            for (series, secondary) in [(&sad, false), (&count, true)] {
                let colour = series.colour;
                let style = colour.stroke_width(2);
                for run in series.runs() {
                    let points = run.iter().map(|&p| Circle::new(p, 3, colour.filled()));
                    if secondary {
                        chart.draw_secondary_series(points)?;
                        chart.draw_secondary_series(LineSeries::new(run, style))?;
                    } else {
                        chart.draw_series(points)?;
                        chart.draw_series(LineSeries::new(run, style))?;
                    }
                }
            }
            draw_legend(&panels[2], 80, &[("sad (left)", BLUE), ("count50 (right)", ORANGE)])?;
        }

        // 4. Motion since the reference frame.
        {
            let scale = f64::from(MOTION_SCALE);
            let tx = Series::new(BLUE, reports, |r| Some(f64::from(r.tx) / scale));
            let tz = Series::new(ORANGE, reports, |r| Some(f64::from(r.tz) / scale));
            let mut chart = chart(&panels[3], "motion since the reference frame", frames.clone(), y_range(&[&tx, &tz], &[0.0]), "mm", 0)?;
            draw_lines(&mut chart, &tx)?;
            draw_lines(&mut chart, &tz)?;
            draw_legend(&panels[3], 10, &[("tx_mm (right)", BLUE), ("tz_mm (ahead)", ORANGE)])?;
        }

        // 5. Attitude change since the reference frame.
        {
            let scale = f64::from(ANGLE_SCALE);
            let yaw = Series::new(BLUE, reports, |r| Some(f64::from(r.dyaw) / scale));
            let pitch = Series::new(ORANGE, reports, |r| Some(f64::from(r.dpitch) / scale));
            let roll = Series::new(PURPLE, reports, |r| Some(f64::from(r.droll) / scale));
            let mut chart = chart(&panels[4], "turn and attitude change since the reference frame", frames, y_range(&[&yaw, &pitch, &roll], &[-0.1, 0.1]), "degrees", 2)?;
            for series in [&yaw, &pitch, &roll] {
                draw_lines(&mut chart, series)?;
            }
            draw_legend(&panels[4], 10, &[("dyaw_deg", BLUE), ("dpitch_deg", ORANGE), ("droll_deg", PURPLE)])?;
        }
        root.present()?;
    }
    Ok(picture)
}
