//! The report stage: the diagnosis as JSON (written in every case, with its `verdict`) and
//! as the short text answer on stdout. The HTML report is [`super::report`].

use std::collections::BTreeMap;

use super::verdict::{Verdict, LIKELY_CAUSES};
use super::Diagnosis;

fn json_num(v: f64, decimals: i32) -> serde_json::Value {
    if !v.is_finite() {
        return serde_json::Value::Null;
    }
    let f = 10f64.powi(decimals);
    serde_json::json!((v * f).round() / f)
}

fn json_raw(v: f64) -> serde_json::Value {
    if v.is_finite() {
        serde_json::json!(v)
    } else {
        serde_json::Value::Null
    }
}

fn json_fits(m: &BTreeMap<&'static str, f64>) -> serde_json::Value {
    serde_json::Value::Object(
        m.iter()
            .map(|(k, v)| (k.to_string(), json_num(*v, 2)))
            .collect(),
    )
}

fn fits(m: &BTreeMap<&'static str, f64>) -> String {
    m.iter()
        .map(|(k, v)| format!("{k} {v:.1} %"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn change(b: &BTreeMap<&'static str, f64>, a: &BTreeMap<&'static str, f64>) -> String {
    b.iter()
        .map(|(k, v)| {
            format!(
                "{k} {v:.1} % -> {:.1} %",
                a.get(k).copied().unwrap_or(f64::NAN)
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The JSON for a diagnosis that could not run past the nominal replay (the replay failed):
/// verdict `unexplained`, the failure with its time and state.
pub fn failure_json(message: &str) -> serde_json::Value {
    serde_json::json!({
        "verdict": Verdict::Unexplained.as_str(),
        "message": format!("The nominal model cannot replay the recording: {message}. Nothing is named. {LIKELY_CAUSES}"),
        "failures": [message],
        "located": [],
        "effects": [],
        "recalibrated": [],
    })
}

/// When a located mismatch happens: a regime ("mostly during high speed") or "throughout
/// the run".
fn when(regime: &str) -> String {
    if regime.starts_with("throughout") {
        regime.to_string()
    } else {
        format!("mostly during {regime}")
    }
}

fn located_json(located: &[super::Located]) -> Vec<serde_json::Value> {
    located
        .iter()
        .map(|l| {
            serde_json::json!({
                "channel": l.channel.name(),
                "fit_pct": json_num(l.fit_pct, 2),
                "windows_s": l.windows_s.iter().map(|w| [json_num(w[0], 4), json_num(w[1], 4)]).collect::<Vec<_>>(),
                "regime": l.regime,
            })
        })
        .collect()
}

fn json_shares(m: &BTreeMap<&'static str, f64>) -> serde_json::Value {
    serde_json::Value::Object(
        m.iter()
            .map(|(k, v)| (k.to_string(), json_num(*v, 4)))
            .collect(),
    )
}

impl Diagnosis {
    /// ", removes 62 % of the mismatch (angle_deg 70 %, p1_kpa 10 %)" for the graded item
    /// `id` (empty when it was not graded).
    fn share_note(&self, id: &str) -> String {
        let Some(i) = self.grade.items.iter().find(|i| i.id == id && i.accepted) else {
            return String::new();
        };
        let total = i.share_check.unwrap_or(i.share_heldout);
        if !total.is_finite() {
            return String::new();
        }
        let per: Vec<String> = i
            .share
            .iter()
            .filter(|(_, v)| v.is_finite())
            .map(|(k, v)| format!("{k} {:.0} %", 100.0 * v))
            .collect();
        format!(
            "; removes {:.0} % of the mismatch{} ({})",
            100.0 * total,
            if i.share_check.is_some() {
                " on the check recording"
            } else {
                " on the held-out tail"
            },
            per.join(", ")
        )
    }

    /// The first line of the answer; pressures logged absolute come first (the rest of
    /// the answer is about an offset of one atmosphere).
    pub fn headline(&self) -> String {
        let answer = self.verdict_line();
        if self.pressures_absolute {
            format!(
                "The pressure columns were logged absolute, not gauge (the fitted offset is one \
                 atmosphere): subtract p_atm or import with reference = \"absolute\". {answer}"
            )
        } else {
            answer
        }
    }

    /// The verdict's sentence.
    fn verdict_line(&self) -> String {
        match self.verdict {
            Verdict::NothingMissing => format!(
                "Nothing is missing: the nominal model explains the recording within its noise (fits {}).",
                fits(&self.fit_before)
            ),
            Verdict::Explained => {
                let names: Vec<&str> = self.effects.iter().map(|e| e.label.as_str()).collect();
                match (names.is_empty(), self.recalibrated.is_empty()) {
                    (false, true) => format!("The model leaves out {}.", names.join(" and ")),
                    (false, false) => format!(
                        "The model leaves out {}, and {} of the plant file's parameters {} off.",
                        names.join(" and "),
                        self.recalibrated.len(),
                        if self.recalibrated.len() == 1 { "is" } else { "are" }
                    ),
                    _ => format!(
                        "Nothing is missing from the model, but {} of the plant file's parameters {} off (recalibration).",
                        self.recalibrated.len(),
                        if self.recalibrated.len() == 1 { "is" } else { "are" }
                    ),
                }
            }
            Verdict::PartlyExplained => {
                let mut names: Vec<String> =
                    self.effects.iter().map(|e| e.label.clone()).collect();
                names.extend(self.recalibrated.iter().map(|r| format!("{} off", r.key)));
                let (x, channel) = self.residual_x_noise;
                let removed = match self.grade.removed_check_total {
                    Some(c) => format!(
                        "{:.0} % of the mismatch on the check recording ({:.0} % on the held-out tail of the training one)",
                        100.0 * c,
                        100.0 * self.grade.removed_heldout_total
                    ),
                    None => format!(
                        "{:.0} % of the mismatch on the held-out tail of the training recording",
                        100.0 * self.grade.removed_heldout_total
                    ),
                };
                let (holds, removes) = if names.len() == 1 {
                    ("holds", "it removes")
                } else {
                    ("hold", "together they remove")
                };
                format!(
                    "Partly explained: {} {holds} on the held-out data; {removes} {removed}, but {x:.0} times the noise remains on {channel}: something else is missing too (where it remains is located below).",
                    names.join(" and "),
                )
            }
            Verdict::Unexplained => {
                let message = {
                    let worst = self
                        .heldout_after
                        .iter()
                        .chain(self.check_after.iter().flatten())
                        .map(|(_, v)| *v)
                        .fold(f64::INFINITY, f64::min);
                    if let Some(term) = &self.stood_in {
                        format!(
                            "Unexplained: the catalogue's best answer ({}) only stands in for a term outside the catalogue: the discovered {term}; no catalogue effect is named (the term is below).",
                            self.best_attempt.join(" + ")
                        )
                    } else if let Some(departs) = &self.check_departs {
                        format!(
                            "Unexplained: the nominal model explains the training recording within its noise (fits {}), but not the check recording ({departs}): the check run went where the training run did not (another load or rig, or an effect the training run's excitation did not reach); no effect is named. Diagnose the check recording itself, or record one run that covers both.",
                            fits(&self.fit_before)
                        )
                    } else if let Some(lost) = &self.check_not_held {
                        format!(
                            "Unexplained: the best answer ({}) fits the training recording but did not hold on the check recording: it makes the check fit worse ({lost}); no effect is named.",
                            self.best_attempt.join(" + ")
                        )
                    } else if self.best_attempt.is_empty() {
                        format!(
                            "Unexplained: the nominal model misses something (fits {}), but nothing in the catalogue or among the plant file's keys explains it on the held-out data; no effect is named.",
                            fits(&self.fit_before)
                        )
                    } else if worst < crate::diagnose::verdict::MIN_HELDOUT_FIT_PCT {
                        format!(
                            "Unexplained: the best answer ({}) still leaves a held-out fit of {worst:.1} % (below 50 %); no effect is named. Perhaps a plant-file key the diagnosis does not refit is off (the muscles' geometry: rest length, initial contraction, end factor; the sprocket radius; the valve's critical ratio): `host-sim identify plant --params KEY` fits any key.",
                            self.best_attempt.join(" + ")
                        )
                    } else {
                        let (x, channel) = self.residual_x_noise;
                        format!(
                            "Unexplained: the best answer ({}) changes the fits {} but still leaves {x:.0} times the noise on {channel} (an explanation leaves at most {:.0} times): something else is off, perhaps a plant-file key the diagnosis does not refit (the muscles' geometry: rest length, initial contraction, end factor; the sprocket radius; the valve's critical ratio; `host-sim identify plant --params KEY` fits any key); no effect is named.",
                            self.best_attempt.join(" + "),
                            change(&self.fit_before, &self.fit_best_attempt),
                            self.max_residual_x_noise
                        )
                    }
                };
                message + &self.bound_note()
            }
            Verdict::NotThisPlant => format!(
                "This recording does not look like this plant (nominal fits {}); no effect is named.",
                fits(&self.fit_before)
            ),
        }
    }

    /// For an unexplained answer: the parameters of the best attempt that ended at the end of
    /// the range the diagnosis searches (a plant-file key then is off by more than the range).
    fn bound_note(&self) -> String {
        self.best_attempt_at_bound
            .iter()
            .map(|h| match h.nominal {
                Some(nominal) => format!(
                    " The refitted {key} ended at {:.3}x the plant file's value, at the end of \
                     the range the diagnosis searches ({:.2}x): the file's value is probably off \
                     by more than that; check it, or fit it with `host-sim identify plant \
                     --params {key}`.",
                    h.value / nominal,
                    h.bound / nominal,
                    key = h.part
                ),
                None => format!(
                    " The {} of {} ended at its bound {} (the true value may lie beyond, or the \
                     effect stands in for something else).",
                    h.param,
                    h.part,
                    crate::validate::Shown(h.bound)
                ),
            })
            .collect()
    }

    /// The JSON of the diagnosis.
    pub fn to_json(&self) -> serde_json::Value {
        let located = located_json(&self.located);
        let effects: Vec<serde_json::Value> = self
            .effects
            .iter()
            .map(|e| {
                let params: serde_json::Map<String, serde_json::Value> = e
                    .params
                    .iter()
                    .map(|(k, v)| (k.clone(), json_raw(*v)))
                    .collect();
                let at_bound: serde_json::Map<String, serde_json::Value> = e
                    .at_bound
                    .iter()
                    .map(|(k, v)| (k.clone(), json_raw(*v)))
                    .collect();
                serde_json::json!({
                    "id": e.id,
                    "params": params,
                    "at_bound": at_bound,
                    "evidence": e.evidence,
                    "score": json_num(e.score, 3),
                })
            })
            .collect();
        let recalibrated: Vec<serde_json::Value> = self
            .recalibrated
            .iter()
            .map(|r| {
                serde_json::json!({
                    "key": r.key,
                    "nominal": json_raw(r.nominal),
                    "fitted": json_raw(r.fitted),
                    "ci95": [json_raw(r.ci95[0]), json_raw(r.ci95[1])],
                    "at_bound": r.at_bound.map(json_raw).unwrap_or(serde_json::Value::Null),
                    "score": json_num(r.score, 3),
                })
            })
            .collect();
        let mut out = serde_json::json!({
            "verdict": self.verdict.as_str(),
            "message": self.headline(),
            "located": located,
            "effects": effects,
            "recalibrated": recalibrated,
            "fit": {"before": json_fits(&self.fit_before), "after": json_fits(&self.fit_after)},
            "heldout_fit": {"before": json_fits(&self.heldout_before), "after": json_fits(&self.heldout_after)},
            "data_notes": self.data_notes,
            "best_attempt": self.best_attempt,
            "best_attempt_at_bound": self.best_attempt_at_bound.iter().map(|h| serde_json::json!({
                "part": h.part,
                "param": h.param,
                "value": json_raw(h.value),
                "bound": json_raw(h.bound),
                "nominal": h.nominal.map(json_raw).unwrap_or(serde_json::Value::Null),
            })).collect::<Vec<_>>(),
            "best_attempt_fit": self.fit_best_attempt.iter().map(|(k, v)| (k.to_string(), json_num(*v, 2))).collect::<serde_json::Map<_, _>>(),
            "residual_x_noise": {
                "worst_channel": self.residual_x_noise.1,
                "times_noise": json_num(self.residual_x_noise.0, 2),
                "limit": json_num(self.max_residual_x_noise, 2),
            },
            "grade": {
                "items": self.grade.items.iter().map(|i| serde_json::json!({
                    "id": i.id,
                    "accepted": i.accepted,
                    "share_by_channel": json_shares(&i.share),
                    "share_heldout": json_num(i.share_heldout, 4),
                    "share_check": i.share_check.map(|v| json_num(v, 4)).unwrap_or(serde_json::Value::Null),
                    "gain_pts": json_num(i.gain_pts, 2),
                    "ci_excludes_null": i.ci_excludes_null,
                    "why_not": i.why_not,
                })).collect::<Vec<_>>(),
                "removed": {
                    "heldout": json_shares(&self.grade.removed_heldout),
                    "check": self.grade.removed_check.as_ref().map(json_shares).unwrap_or(serde_json::Value::Null),
                    "heldout_total": json_num(self.grade.removed_heldout_total, 4),
                    "check_total": self.grade.removed_check_total.map(|v| json_num(v, 4)).unwrap_or(serde_json::Value::Null),
                },
            },
            "remaining": located_json(&self.remaining),
            // The discovery stage's answer, set by the command that runs it after the
            // diagnosis (`host-sim diagnose`); null when it did not run or found nothing.
            "discovered": serde_json::Value::Null,
            // The shift of the valve columns the command applied first (`--shift-valves-ms`).
            "shift_valves_ms": serde_json::Value::Null,
            "lookalikes": self.lookalikes,
            "hints": self.hints,
            "failures": self.failures,
        });
        if let (Some(b), Some(a)) = (&self.check_before, &self.check_after) {
            out["check"] = serde_json::json!({"before": json_fits(b), "after": json_fits(a)});
            if let Some(lost) = &self.check_not_held {
                out["check"]["not_held"] = serde_json::Value::String(lost.clone());
            }
            if let Some(departs) = &self.check_departs {
                out["check"]["departs"] = serde_json::Value::String(departs.clone());
            }
            if let Some(term) = &self.stood_in {
                out["check"]["stood_in"] = serde_json::Value::String(term.clone());
            }
        }
        out["black_box"] = self
            .black_box
            .as_ref()
            .map(|b| b.to_json())
            .unwrap_or(serde_json::Value::Null);
        out
    }

    /// The short human answer for stdout.
    pub fn answer(&self) -> String {
        let mut s = self.headline();
        s.push('\n');
        match self.verdict {
            Verdict::NothingMissing => {
                if let Some(b) = &self.check_before {
                    s += &format!("Check recording: {}.\n", fits(b));
                }
                for d in &self.data_notes {
                    s += &format!("Note: {d}.\n");
                }
                return s;
            }
            Verdict::Explained | Verdict::PartlyExplained => {
                for e in &self.effects {
                    s += &format!(
                        "  - {} ({}): {}{}\n",
                        e.label,
                        e.id,
                        e.description,
                        self.share_note(&e.id)
                    );
                }
                for r in &self.recalibrated {
                    let bound = r
                        .at_bound
                        .map(|b| format!(", at its bound {b:.4e}: the true value may lie beyond"))
                        .unwrap_or_default();
                    s += &format!(
                        "  - recalibrate {} ({}): {:.4e} -> {:.4e} ({:+.1} %), 95 % interval [{:.4e}, {:.4e}]{bound}{}\n",
                        r.key,
                        r.label,
                        r.nominal,
                        r.fitted,
                        100.0 * (r.fitted / r.nominal - 1.0),
                        r.ci95[0],
                        r.ci95[1],
                        self.share_note(&r.key)
                    );
                }
                for i in self.grade.items.iter().filter(|i| !i.accepted) {
                    s += &format!(
                        "  - tried {}, not kept: {}\n",
                        i.id,
                        i.why_not
                            .as_deref()
                            .unwrap_or("it did not hold on the held-out data")
                    );
                }
                s += &format!(
                    "Fit on the training recording: {}.\n",
                    change(&self.fit_before, &self.fit_after)
                );
                if let (Some(b), Some(a)) = (&self.check_before, &self.check_after) {
                    s += &format!("Fit on the check recording: {}.\n", change(b, a));
                }
                for l in &self.remaining {
                    s += &format!(
                        "Remains: {} (fit {:.1} % after the correction) in {} window(s), {}.\n",
                        l.channel.name(),
                        l.fit_pct,
                        l.windows_s.len(),
                        when(&l.regime)
                    );
                }
            }
            Verdict::Unexplained | Verdict::NotThisPlant => {
                for h in &self.hints {
                    s += &format!("  - {h}\n");
                }
                for f in &self.failures {
                    s += &format!("  - {f}\n");
                }
                if let Some(b) = &self.black_box {
                    s += &b.describe();
                    s.push('\n');
                }
                if self.verdict == Verdict::Unexplained {
                    // `diagnose` runs the discovery next; its term, when it keeps one, is
                    // the likelier cause.
                    s += &LIKELY_CAUSES.replacen(
                        "Likely causes:",
                        "Likely causes, unless a term outside the catalogue is missing (the discovery, when it runs, follows):",
                        1,
                    );
                } else {
                    s += LIKELY_CAUSES;
                }
                s.push('\n');
            }
        }
        for l in &self.located {
            let first = l
                .first_departure_s
                .map(|t| format!(", first departs at {t:.3} s"))
                .unwrap_or_default();
            s += &format!(
                "Located: {} (fit {:.1} %) in {} window(s), {}{first}.\n",
                l.channel.name(),
                l.fit_pct,
                l.windows_s.len(),
                when(&l.regime)
            );
        }
        if let Some(first) = self
            .located
            .iter()
            .filter_map(|l| l.first_departure_s.map(|t| (t, l.channel)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
        {
            s += &format!(
                "The first channel to depart is {} (at {:.3} s).\n",
                first.1.name(),
                first.0
            );
        }
        for l in &self.lookalikes {
            s += l;
            s.push('\n');
        }
        for d in &self.data_notes {
            s += &format!("Note: {d}.\n");
        }
        s
    }
}
