//! `--report DIR`: an HTML page (inline SVG plots) a person reads in a browser, with the
//! diagnosis JSON alongside: per channel measured vs nominal vs corrected with the located
//! windows shaded, the residual against the regressor that explains it, and the candidate
//! score table.

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use crate::io::recording::Channel;

use super::discover::Discovery;
use super::screen::Scatter;
use super::{Diagnosis, Series};

/// Most points drawn per line.
pub const MAX_POINTS: usize = 2500;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn channel_svg(
    series: &Series,
    c: Channel,
    windows: &[[f64; 2]],
    title: &str,
) -> Result<String, String> {
    let Some(meas) = &series.measured[c.index()] else {
        return Ok(String::new());
    };
    // The series keeps every `series.stride`-th sample; a line draws every `stride`-th
    // sample of the recording.
    let n = meas.len().min(series.t_s.len());
    let stride = ((series.len / MAX_POINTS).max(1) / series.stride.max(1)).max(1);
    let nom: Vec<f64> = series.nominal.iter().map(|m| c.of(m)).collect();
    let cor: Vec<f64> = series.corrected.iter().map(|m| c.of(m)).collect();
    let [lo, hi] = series.range[c.index()];
    if !lo.is_finite() {
        return Ok(String::new());
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    let t0 = series.t_s[0];
    let t1 = series.t_end_s.max(t0 + 1e-9);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1100, 280)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = crate::io::plot::time_panel(
            &root,
            title,
            Some(c.name()),
            (t0, t1),
            (lo - pad, hi + pad),
        )?;
        chart
            .draw_series(windows.iter().map(|w| {
                Rectangle::new(
                    [(w[0], lo - pad), (w[1], hi + pad)],
                    RGBColor(255, 215, 0).mix(0.25).filled(),
                )
            }))
            .map_err(|e| e.to_string())?;
        let pts = |v: &[f64]| -> Vec<(f64, f64)> {
            (0..n)
                .step_by(stride)
                .map(|k| (series.t_s[k], v[k]))
                .collect()
        };
        use crate::io::plot::{draw_legend, labelled_line};
        labelled_line(
            &mut chart,
            pts(meas),
            BLACK.mix(0.6).stroke_width(2),
            BLACK,
            "measured",
        )?;
        labelled_line(
            &mut chart,
            pts(&nom),
            RED.stroke_width(1),
            RED,
            "nominal model",
        )?;
        labelled_line(
            &mut chart,
            pts(&cor),
            BLUE.stroke_width(1),
            BLUE,
            "corrected model",
        )?;
        draw_legend(&mut chart)?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(svg)
}

fn scatter_svg(s: &Scatter, title: &str) -> Result<String, String> {
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (x, y) in s.points.iter().chain(&s.curve) {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y0 = y0.min(*y);
        y1 = y1.max(*y);
    }
    if !(x0.is_finite() && y0.is_finite()) {
        return Ok(String::new());
    }
    let px = ((x1 - x0) * 0.05).max(1e-9);
    let py = ((y1 - y0) * 0.05).max(1e-9);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 400)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = ChartBuilder::on(&root)
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .caption(title, ("sans-serif", 15))
            .build_cartesian_2d((x0 - px)..(x1 + px), (y0 - py)..(y1 + py))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(s.x_label.as_str())
            .y_desc(s.y_label.as_str())
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(
                s.points
                    .iter()
                    .map(|p| Circle::new(*p, 2, BLUE.mix(0.4).filled())),
            )
            .map_err(|e| e.to_string())?;
        if !s.curve.is_empty() {
            chart
                .draw_series(LineSeries::new(
                    s.curve.iter().copied(),
                    RED.stroke_width(2),
                ))
                .map_err(|e| e.to_string())?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(svg)
}

/// The discovery's answer (empty without one) and the plot of its slot's residual against
/// the best term's argument, the term drawn over it.
fn discovery_section(discovered: Option<&Discovery>) -> Result<String, String> {
    let Some(x) = discovered else {
        return Ok(String::new());
    };
    let mut h = format!(
        "<h2>Discovery: what the catalogue leaves</h2>\n<pre>{}</pre>\n",
        esc(&x.text())
    );
    if let (Some(s), Some(best)) = (&x.scatter, &x.best) {
        let title = format!(
            "{}: residual (blue) and {} (red)",
            best.table.slot.equation(),
            best.table.formula()
        );
        h += &scatter_svg(s, &title)?;
        h.push('\n');
    }
    Ok(h)
}

/// The share of the mismatch each graded item removes, as an HTML table (empty without
/// graded items).
fn grade_table(d: &Diagnosis) -> String {
    let mut h = String::new();
    if d.grade.items.is_empty() {
        return h;
    }
    h += "<h2>Share of the mismatch removed (held-out data)</h2>\n<table><tr><th>item</th><th>kept</th><th>CHECK</th><th>held-out tail</th><th>per channel</th><th>why not kept</th></tr>\n";
    let pct = |v: f64| {
        if v.is_finite() {
            format!("{:.1} %", 100.0 * v)
        } else {
            "-".into()
        }
    };
    for i in &d.grade.items {
        let per: Vec<String> = i
            .share
            .iter()
            .map(|(k, v)| format!("{k} {}", pct(*v)))
            .collect();
        let _ = writeln!(
            h,
            "<tr><td><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            i.id,
            if i.accepted { "yes" } else { "no" },
            i.share_check.map(pct).unwrap_or_else(|| "-".into()),
            pct(i.share_heldout),
            per.join(", "),
            esc(i.why_not.as_deref().unwrap_or(""))
        );
    }
    h += "</table>\n";
    h
}

/// Writes `DIR/index.html` and `DIR/diagnosis.json` (each atomically) and lists them in the
/// folder's manifest (`output`).
pub fn write_report(
    dir: &Path,
    d: &Diagnosis,
    discovered: Option<&Discovery>,
    json: &str,
    train_name: &str,
    check_name: Option<&str>,
) -> Result<(), String> {
    crate::io::atomic::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    crate::io::plot::ensure_font()?;
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>host-sim diagnosis</title>\n<style>body{{font-family:sans-serif;max-width:1150px;margin:auto}} table{{border-collapse:collapse}} td,th{{border:1px solid #999;padding:3px 8px;text-align:right}} td:first-child{{text-align:left}} pre{{background:#f4f4f4;padding:8px;overflow-x:auto}} .ok{{background:#d9f2d9}}</style></head><body>\n<h1>Diagnosis of {}</h1>\n<pre>{}</pre>\n",
        esc(train_name),
        esc(&d.answer())
    );
    let _ = writeln!(h, "<p>Verdict: <b>{}</b></p>", d.verdict.as_str());
    if !d.recalibrated.is_empty() {
        h += "<h2>Recalibrated keys of the plant file</h2>\n<table><tr><th>key</th><th>nominal</th><th>fitted</th><th>95 % interval</th><th>at bound</th></tr>\n";
        for r in &d.recalibrated {
            let _ = writeln!(
                h,
                "<tr><td><code>{}</code></td><td>{:.4e}</td><td>{:.4e}</td><td>[{:.4e}, {:.4e}]</td><td>{}</td></tr>",
                r.key,
                r.nominal,
                r.fitted,
                r.ci95[0],
                r.ci95[1],
                r.at_bound.map(|b| format!("{b:.4e}")).unwrap_or_else(|| "-".into())
            );
        }
        h += "</table>\n";
    }
    h += "<h2>Named effects</h2>\n";
    if d.effects.is_empty() {
        h += "<p>None.</p>\n";
    }
    for e in &d.effects {
        let _ = write!(
            h,
            "<h3>{} (<code>{}</code>), score {:.2}</h3><p>{}</p><ul>",
            esc(&e.label),
            e.id,
            e.score,
            esc(&e.evidence)
        );
        for (k, v) in &e.params {
            let _ = write!(h, "<li><code>{k}</code> = {v:.6e}</li>");
        }
        h += "</ul>\n";
    }
    h += &grade_table(d);
    let _ = write!(h, "<h2>Fits (%)</h2>\n<table><tr><th>channel</th><th>TRAIN nominal</th><th>TRAIN corrected</th><th>CHECK nominal</th><th>CHECK corrected</th></tr>\n");
    for (k, v) in &d.fit_before {
        let a = d.fit_after.get(k).copied().unwrap_or(f64::NAN);
        let cb = d.check_before.as_ref().and_then(|m| m.get(k)).copied();
        let ca = d.check_after.as_ref().and_then(|m| m.get(k)).copied();
        let f = |o: Option<f64>| o.map(|v| format!("{v:.2}")).unwrap_or_else(|| "-".into());
        let _ = writeln!(
            h,
            "<tr><td>{k}</td><td>{v:.2}</td><td>{a:.2}</td><td>{}</td><td>{}</td></tr>",
            f(cb),
            f(ca)
        );
    }
    h += "</table>\n<h2>Where the error lives (TRAIN)</h2>\n<p>Shaded: the located windows of the channel. Black: measured, red: nominal model, blue: corrected model.</p>\n";
    for c in Channel::ALL {
        let loc = d.located.iter().find(|l| l.channel == c);
        let windows: Vec<[f64; 2]> = loc.map(|l| l.windows_s.clone()).unwrap_or_default();
        let title = match loc {
            Some(l) => format!(
                "{} (TRAIN): nominal fit {:.1} %, error during {}",
                c.name(),
                l.fit_pct,
                l.regime
            ),
            None => format!("{} (TRAIN)", c.name()),
        };
        h += &channel_svg(&d.train, c, &windows, &title)?;
        h.push('\n');
    }
    if let Some(cs) = &d.check {
        let _ = writeln!(
            h,
            "<h2>Check recording {}</h2>",
            esc(check_name.unwrap_or(""))
        );
        for c in Channel::ALL {
            h += &channel_svg(cs, c, &[], &format!("{} (CHECK)", c.name()))?;
            h.push('\n');
        }
    }
    if !d.scatters.is_empty() {
        h += "<h2>Residual vs the regressor that explains it</h2>\n";
        for (id, s) in &d.scatters {
            h += &scatter_svg(s, &format!("{id}: equation-error residual"))?;
            h.push('\n');
        }
    }
    h += &discovery_section(discovered)?;
    h += "<h2>Candidate scores</h2>\n<p>Each candidate refitted by output error on the first 70 % of TRAIN and scored on the last 30 %: held-out cost = sum over channels of mean squared error / variance; explained = share of the held-out error beyond noise it removes; BIC delta = change of N ln(cost) + k ln(N) (negative: better).</p>\n<table><tr><th>candidate</th><th>round</th><th>screening R^2</th><th>held-out cost</th><th>explained</th><th>BIC delta</th><th>accepted</th><th>refit s</th><th>parameters</th></tr>\n";
    for s in &d.candidates {
        let params: Vec<String> = s
            .params
            .iter()
            .map(|(k, v)| format!("{k}={v:.4e}"))
            .collect();
        let _ = writeln!(
            h,
            "<tr{}><td>{}</td><td>{}</td><td>{:.3}</td><td>{:.3e}</td><td>{:.1} %</td><td>{:.0}</td><td>{}</td><td>{:.2}</td><td style=\"text-align:left\">{}</td></tr>",
            if s.accepted { " class=\"ok\"" } else { "" },
            s.id, s.round, s.screening, s.heldout_cost, 100.0 * s.explained, s.bic_delta,
            if s.accepted { "yes" } else { "no" },
            s.seconds,
            esc(&params.join(", "))
        );
    }
    let _ = write!(
        h,
        "</table>\n<p>Nominal cost on TRAIN {:.3e}, noise alone {:.3e}.</p>\n<h2>JSON (also in <a href=\"diagnosis.json\">diagnosis.json</a>)</h2>\n<pre>{}</pre>\n</body></html>\n",
        d.nominal_cost,
        d.noise_cost,
        esc(json)
    );
    crate::identify::write_atomic(&dir.join("diagnosis.json"), json.as_bytes())
        .map_err(|e| e.to_string())?;
    crate::identify::write_atomic(&dir.join("index.html"), h.as_bytes())
        .map_err(|e| e.to_string())?;
    crate::io::atomic::write_manifest(dir, &[dir.join("diagnosis.json"), dir.join("index.html")])
        .map_err(|e| e.to_string())?;
    Ok(())
}
