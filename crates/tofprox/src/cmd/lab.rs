//! `tofprox lab ...` (issue: model lab): compare the model with a recording,
//! diagnose the missing effect, add it, list the catalogue.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tofprox_lab::adapter::{spec_from_model, spec_holding_model};
use tofprox_lab::depth_error::depth_split;
use tofprox_lab::diagnose::{compare, diagnose_with, explain};
use tofprox_lab::hold::HoldRequest;
use tofprox_lab::report;
use tofprox_lab::signatures::{SIGNATURE_IDS, cancels_in_4phase};
use tofprox_lab::workflow::{
    add_holding, apply_explained, check_addable, check_out, diagnose_options, load, write_model,
};
use tofprox_lab::{Comparison, Prepared};

use super::lab_export::Export;
use tofprox_model::ModelConfig;

#[derive(clap::Subcommand, Debug)]
pub enum LabCommand {
    /// Fit the model to a recording and show where it fails (residual structure per condition).
    Compare(CompareArgs),
    /// Rank the catalogue effects the model lacks and give a verdict.
    Diagnose(DiagnoseArgs),
    /// Enable an effect, fit it, write the new model file, print the error before and after.
    Add(AddArgs),
    /// Loop diagnose → add until nothing is missing or the rest is unexplained;
    /// write the final model and one report with every step.
    Explain(ExplainArgs),
    /// The effect catalogue: signature in the residual and the physics behind each effect.
    Effects,
}

#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// Recording directory (docs/recording-format.md).
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
    /// Hold the effects' parameters at the model file's values (its own
    /// physics); only per-pixel and per-unit parameters are refitted.
    #[arg(long)]
    pub hold_effects: bool,
    #[command(flatten)]
    pub export: ExportArgs,
    /// Replace existing files in the `--export` directory.
    #[arg(long)]
    pub force: bool,
}

/// `--export DIR` (with `--force`) of compare, diagnose and explain.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// Write residuals and per-pixel maps (.npy) and per-condition tables (.csv) to this
    /// directory (docs/lab-json.md, "Exported files").
    #[arg(long, value_name = "DIR")]
    pub export: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
pub struct DiagnoseArgs {
    /// Recording directory (docs/recording-format.md).
    pub rec: PathBuf,
    /// Model file (TOML).
    #[arg(long)]
    pub model: PathBuf,
    /// Print the verdict as JSON (verdict, evidence, candidates, fit, rms; docs/lab-json.md).
    #[arg(long)]
    pub json: bool,
    /// Write a self-contained HTML report with SVG plots.
    #[arg(long)]
    pub report: Option<PathBuf>,
    #[arg(long, help = tolerance_help())]
    pub tolerance_mm: Option<f64>,
    #[command(flatten)]
    pub export: ExportArgs,
    /// Replace existing files in the `--export` directory.
    #[arg(long)]
    pub force: bool,
}

/// `--tolerance-mm`'s help, its default from the code's constant.
fn tolerance_help() -> String {
    format!(
        "Remaining structure below this depth-equivalent RMS (mm) is not a missing effect \
         [default: {} × the recording's single-acquisition noise]",
        tofprox_lab::diagnose::TOLERANCE_NOISE_SHARE
    )
}

#[derive(clap::Args, Debug)]
pub struct ExplainArgs {
    /// Recording directory (docs/recording-format.md).
    pub rec: PathBuf,
    /// Model file (TOML) to start from.
    #[arg(long)]
    pub model: PathBuf,
    /// Where to write the model with every added effect (nothing is written
    /// when nothing was added).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace `--out` when it exists (also when it is the `--model` itself), and the files
    /// of the `--export` directory.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub export: ExportArgs,
    /// One self-contained HTML report with every step.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Print the steps as JSON.
    #[arg(long)]
    pub json: bool,
    #[arg(long, help = tolerance_help())]
    pub tolerance_mm: Option<f64>,
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
    /// Replace `--out` when it exists (also when it is the `--model` itself).
    #[arg(long)]
    pub force: bool,
    /// Print before/after and the fitted parameters with their standard errors as JSON
    /// (docs/lab-json.md).
    #[arg(long)]
    pub json: bool,
    /// Write a self-contained HTML report with the before/after error curves.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Hold one of the effect's model-file parameters while the others are fitted: at VALUE,
    /// or at the model file's value without one (repeatable; docs/lab.md, "Holding
    /// parameters").
    #[arg(long, value_name = "NAME[=VALUE]")]
    pub hold: Vec<String>,
}

pub fn run(c: LabCommand) -> anyhow::Result<ExitCode> {
    match c {
        LabCommand::Compare(a) => run_compare(a),
        LabCommand::Diagnose(a) => run_diagnose(a),
        LabCommand::Add(a) => run_add(a),
        LabCommand::Explain(a) => run_explain(a),
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

/// The lab's progress callback drawing on `pb`.
fn on_progress(pb: &ProgressBar) -> impl Fn(&str, f64) + Sync + '_ {
    move |stage: &str, f: f64| {
        pb.set_message(stage.to_string());
        pb.set_position((f * 1000.0) as u64);
    }
}

/// Print `json` (with `--json`) or the text `text` makes.
fn emit(
    as_json: bool,
    json: &serde_json::Value,
    text: impl FnOnce() -> anyhow::Result<String>,
) -> anyhow::Result<()> {
    if as_json {
        out(&format!("{}\n", serde_json::to_string_pretty(json)?))
    } else {
        out(&text()?)
    }
}

/// Write the HTML report of a comparison (with its diagnosis or added effect) to `path`.
fn html(
    path: Option<&Path>,
    title: &str,
    prep: &Prepared,
    cmp: &Comparison,
    diagnosis: Option<&tofprox_lab::diagnose::Diagnosis>,
    added: Option<(&str, &tofprox_lab::diagnose::AddOutcome)>,
) -> anyhow::Result<()> {
    let Some(p) = path else { return Ok(()) };
    write_report(
        p,
        &report::html_report(
            title,
            prep.rows,
            prep.cols,
            prep.roi_origin,
            cmp,
            diagnosis,
            added,
        ),
    )
}

fn fit(prep: &Prepared, m: &ModelConfig, pb: &ProgressBar) -> anyhow::Result<Comparison> {
    let cb = on_progress(pb);
    let cmp = compare(prep, &spec_from_model(m), &cb)?;
    warn_unmeasured_noise(&cmp);
    Ok(cmp)
}

/// The one warning a run without measured noise gets (the text and `--json` output also
/// name the noise source).
fn warn_unmeasured_noise(cmp: &Comparison) {
    if !cmp.model.noise.source.measured() {
        tracing::warn!(
            "noise {}, which contain any missing effect",
            cmp.model.noise.source.describe()
        );
    }
}

/// `--export DIR`, when given.
fn export(a: &ExportArgs, prep: &Prepared, what: Export<'_>, force: bool) -> anyhow::Result<()> {
    match &a.export {
        Some(dir) => super::lab_export::write(dir, prep, what, force),
        None => Ok(()),
    }
}

fn write_report(path: &Path, html: &str) -> anyhow::Result<()> {
    tofprox_format::write_atomic(path, html.as_bytes())
        .with_context(|| format!("writing report {}", path.display()))?;
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
    let cmp = if a.hold_effects {
        let (spec, notes) = spec_holding_model(&m, &prep);
        for n in &notes {
            eprintln!("note: {n}");
        }
        let cb = on_progress(&pb);
        let cmp = compare(&prep, &spec, &cb)?;
        warn_unmeasured_noise(&cmp);
        cmp
    } else {
        fit(&prep, &m, &pb)?
    };
    pb.finish_and_clear();
    export(&a.export, &prep, Export::Comparison(&cmp, None), a.force)?;
    emit(a.json, &report::comparison_json(&cmp), || {
        Ok(report::comparison_text(&cmp))
    })?;
    let title = format!(
        "tofprox lab compare: {} vs {}",
        a.rec.display(),
        a.model.display()
    );
    html(a.report.as_deref(), &title, &prep, &cmp, None, None)?;
    Ok(ExitCode::SUCCESS)
}

fn run_diagnose(a: DiagnoseArgs) -> anyhow::Result<ExitCode> {
    let (prep, m) = load(&a.rec, &a.model)?;
    let pb = progress_bar();
    let cmp = fit(&prep, &m, &pb)?;
    let cb = on_progress(&pb);
    let opts = diagnose_options(a.tolerance_mm)?;
    let d = diagnose_with(&prep, &cmp, &opts, &cb)?;
    pb.finish_and_clear();
    export(
        &a.export,
        &prep,
        Export::Comparison(&cmp, Some(&d)),
        a.force,
    )?;
    emit(a.json, &report::diagnosis_json(&d), || {
        Ok(report::diagnosis_text(&d))
    })?;
    let title = format!(
        "tofprox lab diagnose: {} vs {}",
        a.rec.display(),
        a.model.display()
    );
    html(a.report.as_deref(), &title, &prep, &cmp, Some(&d), None)?;
    Ok(ExitCode::SUCCESS)
}

fn run_add(a: AddArgs) -> anyhow::Result<ExitCode> {
    check_addable(&a.effect)?;
    check_out(a.out.as_deref(), a.force)?;
    let hold = a
        .hold
        .iter()
        .map(|h| HoldRequest::parse(h))
        .collect::<Result<Vec<_>, _>>()?;
    let (prep, mut m) = load(&a.data, &a.model)?;
    let pb = progress_bar();
    let cb = on_progress(&pb);
    let (res, notes, held) = add_holding(&prep, &mut m, &a.effect, &a.data, &hold, &cb)?;
    pb.finish_and_clear();
    if let Some(p) = &a.out {
        write_model(&a.model, &m, std::slice::from_ref(&a.effect), p)?;
        eprintln!("model with {} written to {}", a.effect, p.display());
    }
    for n in &notes {
        eprintln!("note: {n}");
    }
    let splits = (
        depth_split(&prep, &res.before),
        depth_split(&prep, &res.after),
    );
    let json = report::add_json(&a.effect, &res, (&splits.0, &splits.1), &held);
    emit(a.json, &json, || {
        let b = tofprox_lab::diagnose::ErrorSummary::of(&res.before);
        let f = tofprox_lab::diagnose::ErrorSummary::of(&res.after);
        let mut t = report::before_after_text((&res.before, &res.after), (&splits.0, &splits.1));
        for (k, v) in &held {
            t.push_str(&format!("held: {k} = {v:.6} (not fitted)\n"));
        }
        // what the model file holds (the file's names and units), not the
        // lab's internal fit parameters
        if let Some(u) = m.user_effects().iter().find(|u| u.name == res.effect.id) {
            t.push_str(&match &a.out {
                Some(p) => format!("user effect as written to {}:\n", p.display()),
                None => "user effect (not written: pass --out FILE):\n".to_string(),
            });
            t.push_str(&u.to_toml());
            t.push_str(&report::fitted_text(
                &res.effect.id,
                &res.params,
                &res.standard_errors,
                (
                    res.standard_errors_note.as_deref(),
                    &res.at_bound,
                    &res.intervals,
                ),
            ));
            return Ok(t);
        }
        let info = tofprox_model::catalogue().iter().find(|e| e.id == a.effect);
        t.push_str(&match &a.out {
            Some(p) => format!("[effects.{}] as written to {}:\n", a.effect, p.display()),
            None => format!("[effects.{}] (not written: pass --out FILE):\n", a.effect),
        });
        t.push_str(&format!(
            "  enabled = {}\n",
            m.effect(&a.effect).is_some_and(|e| e.enabled)
        ));
        for pi in info.map(|e| e.params).unwrap_or_default() {
            if let Some(v) = m.param(&a.effect, pi.name) {
                t.push_str(&format!("  {} = {v:.6}  {}\n", pi.name, pi.unit));
            }
        }
        t.push_str(&report::criteria_change_text(&b, &f));
        t.push_str(&report::fitted_text(
            &a.effect,
            &res.params,
            &res.standard_errors,
            (
                res.standard_errors_note.as_deref(),
                &res.at_bound,
                &res.intervals,
            ),
        ));
        Ok(t)
    })?;
    let title = format!("tofprox lab add {}: {}", a.effect, a.data.display());
    html(
        a.report.as_deref(),
        &title,
        &prep,
        &res.after,
        None,
        Some((&a.effect, &res)),
    )?;
    Ok(ExitCode::SUCCESS)
}

fn run_explain(a: ExplainArgs) -> anyhow::Result<ExitCode> {
    let opts = diagnose_options(a.tolerance_mm)?;
    check_out(a.out.as_deref(), a.force)?;
    let (prep, mut m) = load(&a.rec, &a.model)?;
    let pb = progress_bar();
    let cb = on_progress(&pb);
    let ex = explain(&prep, &spec_from_model(&m), &opts, &cb)?;
    pb.finish_and_clear();
    export(&a.export, &prep, Export::Explanation(&ex), a.force)?;
    let notes = apply_explained(&prep, &mut m, &ex)?;
    match &a.out {
        Some(p) if ex.added.is_empty() => {
            eprintln!("nothing added: {} not written", p.display());
        }
        Some(p) => {
            write_model(&a.model, &m, &ex.added, p)?;
            eprintln!(
                "model with {} written to {}",
                ex.added.join(", "),
                p.display()
            );
        }
        None => {}
    }
    for n in &notes {
        eprintln!("note: {n}");
    }
    emit(a.json, &report::explanation_json(&ex), || {
        let mut t = String::new();
        for (i, st) in ex.steps.iter().enumerate() {
            t.push_str(&format!("── step {} ──\n", i + 1));
            t.push_str(&report::diagnosis_text(&st.diagnosis));
            if let Some(e) = &st.added {
                t.push_str(&format!("→ add {e}\n"));
            }
        }
        t.push_str(&format!(
            "final verdict: {} after adding [{}]\n",
            ex.verdict().as_str(),
            ex.added.join(", ")
        ));
        if let (Some(first), Some(last)) = (ex.steps.first(), ex.steps.last())
            && !ex.added.is_empty()
        {
            let (b, f) = (&first.comparison, &last.comparison);
            t.push_str(&report::before_after_text(
                (b, f),
                (&depth_split(&prep, b), &depth_split(&prep, f)),
            ));
        }
        for f in &ex.fitted {
            t.push_str(&report::fitted_text(
                &f.effect,
                &f.params,
                &f.standard_errors,
                (f.standard_errors_note.as_deref(), &f.at_bound, &f.intervals),
            ));
        }
        if let Some(why) = &ex.stopped {
            t.push_str(&format!("explain stopped: {why}\n"));
        }
        Ok(t)
    })?;
    if let Some(p) = &a.report {
        let title = format!(
            "tofprox lab explain: {} from {}",
            a.rec.display(),
            a.model.display()
        );
        write_report(
            p,
            &report::explain_html(&title, prep.rows, prep.cols, prep.roi_origin, &ex),
        )?;
    }
    // could not explain: the reason is printed above, the exit status says so
    Ok(match &ex.stopped {
        Some(why) => {
            eprintln!("error: could not explain the recording: {why}");
            ExitCode::from(1)
        }
        None => ExitCode::SUCCESS,
    })
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
