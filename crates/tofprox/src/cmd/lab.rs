//! `tofprox lab ...` (issue: model lab): compare the model with a recording,
//! diagnose the missing effect, add it, list the catalogue.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tofprox_lab::adapter::{load_recording, spec_from_model, write_effect};
use tofprox_lab::diagnose::{add_effect, compare, diagnose};
use tofprox_lab::report;
use tofprox_lab::signatures::{SIGNATURE_IDS, cancels_in_4phase};
use tofprox_lab::{Comparison, Prepared};
use tofprox_model::ModelConfig;

#[derive(clap::Subcommand, Debug)]
pub enum LabCommand {
    /// Fit the model to a recording and show where it fails (residual structure per condition).
    Compare(CompareArgs),
    /// Rank the catalogue effects the model lacks and give a verdict.
    Diagnose(DiagnoseArgs),
    /// Enable an effect, fit it, write the new model file, print the error before and after.
    Add(AddArgs),
    /// The effect catalogue: signature in the residual and the physics behind each effect.
    Effects,
}

#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// Recording directory (version 1 format).
    pub rec: PathBuf,
    /// Model file (TOML) whose enabled effects are fitted.
    #[arg(long)]
    pub model: PathBuf,
    /// Write a self-contained HTML report with SVG plots.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Print JSON to stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct DiagnoseArgs {
    /// Recording directory (version 1 format).
    pub rec: PathBuf,
    /// Model file (TOML).
    #[arg(long)]
    pub model: PathBuf,
    /// Print the verdict as JSON (the `diagnose --json` document of `tofprox_lab::report`).
    #[arg(long)]
    pub json: bool,
    /// Write a self-contained HTML report with SVG plots.
    #[arg(long)]
    pub report: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
pub struct AddArgs {
    /// Catalogue id of the effect to add (see `tofprox lab effects`).
    pub effect: String,
    /// Model file (TOML) to start from.
    #[arg(long)]
    pub model: PathBuf,
    /// Recording directory to fit on.
    #[arg(long)]
    pub data: PathBuf,
    /// Where to write the model with the effect enabled and fitted.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print before/after as JSON (the `add --json` document of `tofprox_lab::report`).
    #[arg(long)]
    pub json: bool,
    /// Write a self-contained HTML report with the before/after error curves.
    #[arg(long)]
    pub report: Option<PathBuf>,
}

pub fn run(c: LabCommand) -> anyhow::Result<ExitCode> {
    match c {
        LabCommand::Compare(a) => run_compare(a),
        LabCommand::Diagnose(a) => run_diagnose(a),
        LabCommand::Add(a) => run_add(a),
        LabCommand::Effects => run_effects(),
    }
}

fn progress_bar() -> ProgressBar {
    let pb = ProgressBar::with_draw_target(Some(1000), ProgressDrawTarget::stderr());
    if let Ok(st) = ProgressStyle::with_template("{msg:>14} [{bar:30}] {percent:>3}% {elapsed}") {
        pb.set_style(st.progress_chars("=> "));
    }
    pb
}

fn load(rec: &Path, model: &Path) -> anyhow::Result<(Prepared, ModelConfig)> {
    let m = ModelConfig::load(model).with_context(|| format!("model file {}", model.display()))?;
    let ds = load_recording(rec)?;
    let prep = Prepared::new(&ds).with_context(|| format!("recording {}", rec.display()))?;
    Ok((prep, m))
}

fn fit(prep: &Prepared, m: &ModelConfig, pb: &ProgressBar) -> anyhow::Result<Comparison> {
    let cb = |stage: &str, f: f64| {
        pb.set_message(stage.to_string());
        pb.set_position((f * 1000.0) as u64);
    };
    Ok(compare(prep, &spec_from_model(m), &cb)?)
}

fn write_report(path: &Path, html: &str) -> anyhow::Result<()> {
    std::fs::write(path, html).with_context(|| format!("writing report {}", path.display()))?;
    eprintln!("report written to {}", path.display());
    Ok(())
}

/// Print to stdout; a closed pipe (`| head`) ends the output quietly.
fn out(s: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut o = std::io::stdout().lock();
    match o.write_all(s.as_bytes()).and_then(|_| o.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}

fn run_compare(a: CompareArgs) -> anyhow::Result<ExitCode> {
    let (prep, m) = load(&a.rec, &a.model)?;
    let pb = progress_bar();
    let cmp = fit(&prep, &m, &pb)?;
    pb.finish_and_clear();
    if a.json {
        out(&format!(
            "{}\n",
            serde_json::to_string_pretty(&report::comparison_json(&cmp))?
        ))?;
    } else {
        out(&report::comparison_text(&cmp))?;
    }
    if let Some(p) = &a.report {
        let title = format!(
            "tofprox lab compare: {} vs {}",
            a.rec.display(),
            a.model.display()
        );
        write_report(
            p,
            &report::html_report(&title, prep.rows, prep.cols, &cmp, None, None),
        )?;
    }
    Ok(ExitCode::SUCCESS)
}

fn run_diagnose(a: DiagnoseArgs) -> anyhow::Result<ExitCode> {
    let (prep, m) = load(&a.rec, &a.model)?;
    let pb = progress_bar();
    let cmp = fit(&prep, &m, &pb)?;
    let cb = |stage: &str, f: f64| {
        pb.set_message(stage.to_string());
        pb.set_position((f * 1000.0) as u64);
    };
    let d = diagnose(&prep, &cmp, &cb)?;
    pb.finish_and_clear();
    if a.json {
        out(&format!(
            "{}\n",
            serde_json::to_string_pretty(&report::diagnosis_json(&d))?
        ))?;
    } else {
        out(&report::diagnosis_text(&d))?;
    }
    if let Some(p) = &a.report {
        let title = format!(
            "tofprox lab diagnose: {} vs {}",
            a.rec.display(),
            a.model.display()
        );
        write_report(
            p,
            &report::html_report(&title, prep.rows, prep.cols, &cmp, Some(&d), None),
        )?;
    }
    Ok(ExitCode::SUCCESS)
}

fn run_add(a: AddArgs) -> anyhow::Result<ExitCode> {
    if !SIGNATURE_IDS.contains(&a.effect.as_str()) {
        anyhow::bail!(
            "the lab cannot add `{}`; it can add: {}",
            a.effect,
            SIGNATURE_IDS.join(", ")
        );
    }
    let (prep, mut m) = load(&a.data, &a.model)?;
    let pb = progress_bar();
    let cb = |stage: &str, f: f64| {
        pb.set_message(stage.to_string());
        pb.set_position((f * 1000.0) as u64);
    };
    let res = add_effect(&prep, &spec_from_model(&m), &a.effect, &cb)?;
    pb.finish_and_clear();
    let notes = write_effect(&mut m, &a.effect, &res.params, &res.after.model, &prep)?;
    if let Some(p) = &a.out {
        std::fs::write(p, m.to_toml_string())
            .with_context(|| format!("writing model {}", p.display()))?;
        eprintln!("model with {} written to {}", a.effect, p.display());
    }
    for n in &notes {
        eprintln!("note: {n}");
    }
    if a.json {
        out(&format!(
            "{}\n",
            serde_json::to_string_pretty(&report::add_json(&a.effect, &res))?
        ))?;
    } else {
        let b = tofprox_lab::diagnose::ErrorSummary::of(&res.before);
        let f = tofprox_lab::diagnose::ErrorSummary::of(&res.after);
        let mut t = format!(
            "{:<8} {:>12} {:>14} {:>14} {:>10}\n",
            "", "raw [LSB]", "2-phase [mm]", "4-phase [mm]", "χ²/dof"
        );
        for (n, e) in [("before", &b), ("after", &f)] {
            t.push_str(&format!(
                "{:<8} {:>12.3} {:>14.2} {:>14.2} {:>10.3}\n",
                n, e.raw_lsb, e.depth_2phase_mm, e.depth_4phase_mm, e.chi2_per_dof
            ));
        }
        for (k, v) in &res.params {
            t.push_str(&format!("  {}.{k} = {v:.6}\n", a.effect));
        }
        out(&t)?;
    }
    if let Some(p) = &a.report {
        let title = format!("tofprox lab add {}: {}", a.effect, a.data.display());
        write_report(
            p,
            &report::html_report(
                &title,
                prep.rows,
                prep.cols,
                &res.after,
                None,
                Some((&a.effect, &res)),
            ),
        )?;
    }
    Ok(ExitCode::SUCCESS)
}

fn run_effects() -> anyhow::Result<ExitCode> {
    let mut t = String::new();
    for e in tofprox_model::catalogue() {
        let lab = SIGNATURE_IDS.contains(&e.id);
        t.push_str(&format!(
            "{} — {}\n  thesis: {}\n  residual signature: {}\n  physics: {}\n  lab: {}{}\n\n",
            e.id,
            e.title,
            e.thesis_ref,
            e.signature,
            e.explanation,
            if lab {
                "can diagnose and add"
            } else {
                "fitted as part of the lab model, or noise only"
            },
            if lab && cancels_in_4phase(e.id) {
                " (cancels in 4-phase, visible in 2-phase)"
            } else {
                ""
            }
        ));
    }
    out(&t)?;
    Ok(ExitCode::SUCCESS)
}
