//! Measured vs simulated channel plots with `plotters` (PNG or SVG by file extension).
//!
//! Text is laid out with `ab_glyph` (pure Rust, no fontconfig/freetype build dependency) from
//! a TrueType font found at run time: `$HOST_SIM_FONT`, else a common system sans font.

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::io::recording::{Channel, Recording};

/// Fonts tried when `$HOST_SIM_FONT` is not set.
const FONT_CANDIDATES: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu-sans-fonts/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
    "/usr/share/fonts/noto/NotoSans-Regular.ttf",
    "/usr/share/fonts/truetype/noto/NotoSans-Regular.ttf",
    "/Library/Fonts/Arial.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
    "C:\\Windows\\Fonts\\arial.ttf",
];

/// Registers the plot font once; the error says where we looked.
pub(crate) fn ensure_font() -> Result<(), String> {
    static FONT: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    FONT.get_or_init(|| {
        let from_env = std::env::var_os("HOST_SIM_FONT").map(PathBuf::from);
        let candidates: Vec<PathBuf> = match &from_env {
            Some(p) => vec![p.clone()],
            None => FONT_CANDIDATES.iter().map(PathBuf::from).collect(),
        };
        for p in &candidates {
            if let Ok(bytes) = std::fs::read(p) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                return plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
                    .map_err(|_| format!("{}: not a usable TrueType/OpenType font", p.display()));
            }
        }
        Err(match from_env {
            Some(p) => format!("HOST_SIM_FONT={}: cannot read the font file", p.display()),
            None => format!(
                "no font for the plot text found (tried {}); set HOST_SIM_FONT=/path/to/font.ttf",
                FONT_CANDIDATES.join(", ")
            ),
        })
    })
    .clone()
}

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{}: unsupported plot format (use .png or .svg)", .0.display())]
    Format(PathBuf),
    #[error("{}: {message}", path.display())]
    Draw { path: PathBuf, message: String },
    #[error("{}: nothing to plot (no output channel)", .0.display())]
    Empty(PathBuf),
}

/// A figure that can draw itself on any `plotters` backend (a generic method, which a closure
/// cannot have: [`write_plot`] picks the backend from the file extension).
pub(crate) trait Figure {
    /// Draws the whole figure on `root`.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

/// Writes `figure` at `size` pixels to `path` (`.png` or `.svg`, by extension): drawn into a
/// temporary file next to `path` (same extension, so the backend picks the encoder), given
/// the permissions an output file gets, and renamed over `path`. A failed plot leaves the old
/// `path` as it was.
pub(crate) fn write_plot(
    path: &Path,
    size: (u32, u32),
    figure: &impl Figure,
) -> Result<(), PlotError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ext != "png" && ext != "svg" {
        return Err(PlotError::Format(path.to_owned()));
    }
    let draw_err = |message: String| PlotError::Draw {
        path: path.to_owned(),
        message,
    };
    ensure_font().map_err(draw_err)?;
    // The one atomic writer: drawn into a temporary file with the same extension (the
    // backend picks the encoder from it), renamed over `path` when complete.
    crate::io::atomic::write_via_path(path, |tmp| {
        if ext == "png" {
            let root = BitMapBackend::new(tmp, size).into_drawing_area();
            figure.draw(&root)?;
            root.present().map_err(|e| e.to_string())
        } else {
            let root = SVGBackend::new(tmp, size).into_drawing_area();
            figure.draw(&root)?;
            root.present().map_err(|e| e.to_string())
        }
    })
    .map_err(|e| match e {
        crate::io::atomic::ViaPathError::Write(m) => draw_err(m),
        crate::io::atomic::ViaPathError::Io(e) => draw_err(e.to_string()),
    })?;
    Ok(())
}

/// Draws one panel per output channel of `model`; `reference` (measured) is drawn under it
/// where it has the channel. Written to a temporary file and renamed over `path`.
pub fn plot_comparison(
    path: &Path,
    reference: Option<&Recording>,
    model: &Recording,
) -> Result<(), PlotError> {
    let channels: Vec<Channel> = Channel::ALL
        .into_iter()
        .filter(|c| model.channel(*c).is_some())
        .collect();
    if channels.is_empty() {
        return Err(PlotError::Empty(path.to_owned()));
    }
    struct Comparison<'a> {
        reference: Option<&'a Recording>,
        model: &'a Recording,
        channels: &'a [Channel],
    }
    impl Figure for Comparison<'_> {
        fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
            draw(root, self.reference, self.model, self.channels)
        }
    }
    write_plot(
        path,
        (1200u32, 260 * channels.len() as u32),
        &Comparison {
            reference,
            model,
            channels: &channels,
        },
    )
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    reference: Option<&Recording>,
    model: &Recording,
    channels: &[Channel],
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let panels = root.split_evenly((channels.len(), 1));
    for (panel, c) in panels.iter().zip(channels) {
        let sim = model.channel(*c).unwrap();
        let meas = reference.and_then(|r| r.channel(*c).map(|m| (r, m)));
        let t0 = model.t_s.first().copied().unwrap_or(0.0);
        let t1 = model.t_s.last().copied().unwrap_or(1.0).max(t0 + 1e-9);
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for v in sim.iter().chain(meas.iter().flat_map(|(_, m)| m.iter())) {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
        let pad = ((hi - lo) * 0.05).max(1e-6);
        let mut chart = time_panel(
            panel,
            c.name(),
            Some(c.name()),
            (t0, t1),
            (lo - pad, hi + pad),
        )?;
        if let Some((r, m)) = meas {
            labelled_line(
                &mut chart,
                r.t_s.iter().copied().zip(m.iter().copied()),
                BLUE.stroke_width(2),
                BLUE,
                "measured",
            )?;
        }
        labelled_line(
            &mut chart,
            model.t_s.iter().copied().zip(sim.iter().copied()),
            RED.stroke_width(1),
            RED,
            "simulated",
        )?;
        draw_legend(&mut chart)?;
    }
    Ok(())
}

/// A chart of values over time.
pub(crate) type TimeChart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// A panel of values over time `t_s.0..t_s.1` and `y.0..y.1` on `area`: caption, axes and
/// mesh drawn (the x axis is `t_s`; the y axis is labelled `y_desc` when given).
pub(crate) fn time_panel<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
    y_desc: Option<&str>,
    t_s: (f64, f64),
    y: (f64, f64),
) -> Result<TimeChart<'a, DB>, String> {
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .x_label_area_size(28)
        .y_label_area_size(70)
        .caption(caption, ("sans-serif", 16))
        .build_cartesian_2d(t_s.0..t_s.1, y.0..y.1)
        .map_err(|e| e.to_string())?;
    let mut mesh = chart.configure_mesh();
    mesh.x_desc("t_s");
    if let Some(d) = y_desc {
        mesh.y_desc(d);
    }
    mesh.draw().map_err(|e| e.to_string())?;
    Ok(chart)
}

/// Draws `points` with `style` and a legend entry `label` in `color`.
pub(crate) fn labelled_line<'a, DB: DrawingBackend + 'a>(
    chart: &mut TimeChart<'a, DB>,
    points: impl IntoIterator<Item = (f64, f64)>,
    style: ShapeStyle,
    color: RGBColor,
    label: impl Into<String>,
) -> Result<(), String> {
    chart
        .draw_series(LineSeries::new(points, style))
        .map_err(|e| e.to_string())?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
    Ok(())
}

/// Draws the legend of the labelled lines.
pub(crate) fn draw_legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut TimeChart<'a, DB>,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())
}
