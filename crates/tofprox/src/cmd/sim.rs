//! `tofprox sim ...` and `tofprox model ...` (issue: physical model).
//!
//! - `sim sweep`: a calibration-session-like recording (dark frames, a 24-phase
//!   correlation capture, distance sweeps over exposures/ambient/temperature)
//!   with ground truth in `[capture.conditions]`; parallel over captures,
//!   deterministic for a seed whatever the thread count.
//! - `sim scene`: a scripted scene (hand, face, wall) over time.
//! - `sim figures`: the thesis figures as SVG.
//! - `model effects` / `model show`: the catalogue and a model file.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use tofprox_format::Recording;
use tofprox_model::figures::Figure;
use tofprox_model::sweep::{self, PlannedCapture, SweepPlan};
use tofprox_model::{
    CaptureRequest, ModelConfig, SceneScript, SensorGeometry, Simulator, catalogue,
};

#[derive(clap::Subcommand, Debug)]
pub enum SimCommand {
    /// Simulate a calibration session: dark frames, a 24-phase correlation capture and distance sweeps.
    Sweep(SweepArgs),
    /// Simulate a scripted scene (hand approaching/leaving, face, wall) over time.
    Scene(SceneArgs),
    /// Regenerate the thesis figures (3.7, 3.8, 3.9, 5.1, 5.7, 5.8) as SVG.
    Figures(FiguresArgs),
}

#[derive(clap::Subcommand, Debug)]
pub enum ModelCommand {
    /// List the effect catalogue with physics, thesis reference and parameters.
    Effects(EffectsArgs),
    /// Validate a model file and show its effects and parameters.
    Show(ShowArgs),
    /// Print a preset's model file as shipped in config/model (generated from the registry).
    Preset(PresetArgs),
}

#[derive(clap::Args, Debug)]
pub struct PresetArgs {
    /// The preset: baseline, full or ideal.
    #[arg(value_parser = parse_preset)]
    pub preset: tofprox_model::preset::Preset,
}

fn parse_preset(name: &str) -> Result<tofprox_model::preset::Preset, String> {
    tofprox_model::preset::Preset::parse(name)
        .ok_or_else(|| format!("`{name}` is not a preset (baseline, full, ideal)"))
}

#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// Model file (config/model/*.toml).
    #[arg(long)]
    pub model: PathBuf,
    /// Simulate the conditions of this recording instead of a sweep: its
    /// window, ADC and modulation frequency, and capture by capture its
    /// phases, exposure, illumination, averaging, distance_m, reflectivity,
    /// ambient_klux and temperature_c (the model's inputs). Its other
    /// conditions are copied to the output unchanged and listed as ignored;
    /// illuminated captures without distance_m are skipped.
    #[arg(long, conflicts_with_all = [
        "distances", "exposures", "phases", "ambient", "temperatures", "reflectivity",
        "repeats", "averaged", "window", "correlation_distance",
    ])]
    pub like: Option<PathBuf>,
    /// Distances: FROM:TO:STEP or a comma list, in metres.
    #[arg(long, default_value = "0.15:1.80:0.05")]
    pub distances: String,
    /// Exposure times in µs (comma list).
    #[arg(long, default_value = "500,1000", value_delimiter = ',')]
    pub exposures: Vec<f64>,
    /// Raw images per capture: 2 (0°, 90°), 4 (0°, 90°, 180°, 270°) or 24 (correlation).
    #[arg(long, default_value_t = 4)]
    pub phases: usize,
    /// Ambient light levels in klux (comma list).
    #[arg(long, default_value = "0", value_delimiter = ',')]
    pub ambient: Vec<f64>,
    /// Temperatures in °C (comma list).
    #[arg(long, default_value = "25", value_delimiter = ',')]
    pub temperatures: Vec<f64>,
    /// Target reflectivity.
    #[arg(long, default_value_t = 0.9)]
    pub reflectivity: f64,
    /// Repeated captures per condition.
    #[arg(long, default_value_t = 1)]
    pub repeats: u32,
    /// Acquisitions averaged per capture (1: single acquisitions stored as uint16).
    #[arg(long, default_value_t = 1)]
    pub averaged: u32,
    /// Read-out window ROW,COL,HEIGHT,WIDTH on the 172x224 array (default: full array).
    #[arg(long)]
    pub window: Option<String>,
    /// Distance of the 24-phase correlation capture in metres.
    #[arg(long, default_value_t = 1.0)]
    pub correlation_distance: f64,
    /// Seed of the sensor's fixed patterns and of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output recording directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the recording already in `--out`.
    #[arg(long)]
    pub force: bool,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum ScriptArg {
    Hand,
    Face,
    Wall,
}

#[derive(clap::Args, Debug)]
pub struct SceneArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Built-in script.
    #[arg(
        long,
        value_enum,
        default_value = "hand",
        conflicts_with = "script_file"
    )]
    pub script: ScriptArg,
    /// A scene script TOML file (fields of SceneScript) instead of a built-in one.
    #[arg(long)]
    pub script_file: Option<PathBuf>,
    /// Duration in seconds.
    #[arg(long, default_value_t = 8.0)]
    pub duration: f64,
    /// Frame rate in Hz.
    #[arg(long, default_value_t = 5.0)]
    pub rate: f64,
    /// Raw images per frame: 2 or 4.
    #[arg(long, default_value_t = 2)]
    pub phases: usize,
    /// Exposure time in µs.
    #[arg(long, default_value_t = 500.0)]
    pub exposure_us: f64,
    /// Read-out window ROW,COL,HEIGHT,WIDTH.
    #[arg(long)]
    pub window: Option<String>,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output recording directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the recording already in `--out`.
    #[arg(long)]
    pub force: bool,
}

#[derive(clap::Args, Debug)]
pub struct FiguresArgs {
    /// Output directory for the SVG files.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(clap::Args, Debug)]
pub struct EffectsArgs {
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct ShowArgs {
    /// Model file.
    pub model: PathBuf,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

pub fn run_sim(c: SimCommand) -> anyhow::Result<ExitCode> {
    match c {
        SimCommand::Sweep(a) => sweep(a),
        SimCommand::Scene(a) => scene(a),
        SimCommand::Figures(a) => figures(a),
    }
}

pub fn run_model(c: ModelCommand) -> anyhow::Result<ExitCode> {
    match c {
        ModelCommand::Effects(a) => effects(a),
        ModelCommand::Show(a) => show(a),
        ModelCommand::Preset(a) => {
            print!("{}", a.preset.file_text());
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// Parse `FROM:TO:STEP` or a comma list of distances.
fn parse_distances(s: &str) -> anyhow::Result<Vec<f64>> {
    let bad = || format!("--distances `{s}`: expected FROM:TO:STEP or a comma list of metres");
    let sep = if s.contains(':') { ':' } else { ',' };
    let parts: Vec<f64> = s
        .split(sep)
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(bad)?;
    match parts[..] {
        [from, to, step] if sep == ':' => {
            Ok(sweep::distance_range(from, to, step).with_context(bad)?)
        }
        _ if sep == ':' => bail!(bad()),
        _ => Ok(parts),
    }
}

fn geometry_for(window: &Option<String>) -> anyhow::Result<SensorGeometry> {
    let full = SensorGeometry::irs1645();
    let Some(w) = window else { return Ok(full) };
    let bad = || format!("--window `{w}`: expected ROW,COL,HEIGHT,WIDTH (non-negative integers)");
    let v: Vec<usize> = w
        .split(',')
        .map(|x| x.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .with_context(bad)?;
    match v[..] {
        [r, c, h, wd] => Ok(full.window(r, c, h, wd).with_context(bad)?),
        _ => bail!(bad()),
    }
}

fn progress(n: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(n as u64);
    pb.set_style(
        ProgressStyle::with_template("{prefix} [{bar:40}] {pos}/{len} captures ({eta} left)")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}

/// Simulate `plan` into a new recording `out` (a progress bar on the terminal).
fn write_recording(
    sim: &Simulator,
    plan: &[PlannedCapture],
    seed: u64,
    out: &Path,
    description: String,
    force: bool,
    what: &str,
) -> anyhow::Result<usize> {
    let mut writer = super::new_recording(out, *sim.geometry(), Some(description), force)?;
    let pb = progress(plan.len(), what);
    sweep::write_plan(sim, plan, seed, &mut writer, || pb.inc(1))?;
    pb.finish_and_clear();
    let n = writer.len();
    // only a sweep written to its end is complete (a killed one stays marked incomplete)
    writer.finish().map_err(|e| super::output_error(out, e))?;
    Ok(n)
}

fn load_model(path: &Path) -> anyhow::Result<ModelConfig> {
    Ok(ModelConfig::load(path)?)
}

/// `sim sweep --like REC`: the recording's own conditions through the model.
fn sweep_like(a: &SweepArgs, like: &Path) -> anyhow::Result<ExitCode> {
    let model = load_model(&a.model)?;
    let rec = Recording::open(like)
        .with_context(|| format!("cannot open recording {}", like.display()))?;
    let plan = sweep::plan_like(&rec)?;
    let sim = Simulator::new(&model, *rec.sensor(), a.seed)?;
    let description = format!(
        "tofprox sim sweep --like {}: model {} (effects: {}), seed {}",
        like.display(),
        a.model.display(),
        model.enabled_effects().join(", "),
        a.seed
    );
    let n = write_recording(
        &sim,
        &plan.captures,
        a.seed,
        &a.out,
        description,
        a.force,
        "sweep --like",
    )?;
    if !plan.ignored.is_empty() {
        eprintln!(
            "conditions copied but not simulated (no model input): {}",
            plan.ignored.join(", ")
        );
    }
    if plan.skipped > 0 {
        eprintln!(
            "skipped {} illuminated captures without distance_m",
            plan.skipped
        );
    }
    eprintln!(
        "wrote {n} captures like {} to {}",
        like.display(),
        a.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn sweep(a: SweepArgs) -> anyhow::Result<ExitCode> {
    if let Some(like) = &a.like {
        return sweep_like(&a, like);
    }
    let model = load_model(&a.model)?;
    let plan = SweepPlan {
        distances_m: parse_distances(&a.distances)?,
        exposures_us: a.exposures.clone(),
        phases: a.phases,
        ambient_klux: a.ambient.clone(),
        temperatures_c: a.temperatures.clone(),
        reflectivity: a.reflectivity,
        repeats: a.repeats,
        averaged: a.averaged,
        correlation_distance_m: a.correlation_distance,
    }
    .captures()?;
    let geometry = geometry_for(&a.window)?;
    let sim = Simulator::new(&model, geometry, a.seed)?;
    let description = format!(
        "tofprox sim sweep: model {} (effects: {}), seed {}",
        a.model.display(),
        model.enabled_effects().join(", "),
        a.seed
    );
    let n = write_recording(&sim, &plan, a.seed, &a.out, description, a.force, "sweep")?;
    eprintln!("wrote {n} captures to {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}

fn scene(a: SceneArgs) -> anyhow::Result<ExitCode> {
    let model = load_model(&a.model)?;
    let script = match &a.script_file {
        Some(p) => {
            let text = tofprox_format::limits::read_text_bounded(
                p,
                tofprox_format::limits::MAX_TOML_BYTES,
            )?;
            toml::from_str::<SceneScript>(&text)
                .with_context(|| format!("{}: invalid scene script", p.display()))?
        }
        None => match a.script {
            ScriptArg::Hand => SceneScript::hand(),
            ScriptArg::Face => SceneScript::face(),
            ScriptArg::Wall => SceneScript::wall(1.0),
        },
    };
    script.validate()?;
    if !(a.duration.is_finite() && a.duration > 0.0 && a.duration <= 3600.0) {
        bail!("--duration {}: allowed (0, 3600] s", a.duration);
    }
    if !(a.rate.is_finite() && a.rate > 0.0 && a.rate <= 1000.0) {
        bail!("--rate {}: allowed (0, 1000] Hz", a.rate);
    }
    let n = (a.duration * a.rate).floor() as usize;
    if n == 0 || n > 100_000 {
        bail!("duration × rate gives {n} frames, allowed 1..=100000");
    }
    if a.phases == 24 {
        bail!("--phases for scenes: 2 or 4");
    }
    let phases = sweep::phases_for(a.phases)?;
    let geometry = geometry_for(&a.window)?;
    let sim = Simulator::new(&model, geometry, a.seed)?;
    let plan: Vec<PlannedCapture> = (0..n)
        .map(|i| {
            let t = i as f64 / a.rate;
            let mut request = CaptureRequest::with_phases(phases.clone(), a.exposure_us);
            request.averaged = 1;
            let reflectivity = if script.object_distance_m(t).is_some() {
                script.object_reflectivity
            } else {
                script.wall_reflectivity
            };
            let mut p = PlannedCapture::wall(request, script.centre_distance_m(t), reflectivity);
            p.scene = script.at(t);
            p.conditions.insert("time_s".into(), t);
            p
        })
        .collect();
    sweep::validate(&plan)?;
    let description = format!(
        "tofprox sim scene: {:?} script, model {}, seed {}",
        script.kind,
        a.model.display(),
        a.seed
    );
    let n = write_recording(&sim, &plan, a.seed, &a.out, description, a.force, "scene")?;
    eprintln!("wrote {n} frames to {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}

fn figures(a: FiguresArgs) -> anyhow::Result<ExitCode> {
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let figs = tofprox_model::figures::all()?;
    for f in &figs {
        let path = a.out.join(format!("{}.svg", f.id));
        render_svg(f, &path).with_context(|| format!("cannot render {}", path.display()))?;
        println!("{}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// Render a figure as SVG with the one chart component (legend below the
/// plot, coincident series announced); with [`Figure::offsets`] the series drawn apart, each
/// legend entry naming its shift.
pub fn render_svg(f: &Figure, path: &Path) -> anyhow::Result<()> {
    use tofprox_chart::{LineChart, line_chart};
    if !f
        .series
        .iter()
        .flat_map(|s| &s.points)
        .any(|(x, y)| x.is_finite() && y.is_finite())
    {
        bail!("figure {} has no data", f.id);
    }
    let unit = f
        .y_label
        .rsplit_once('[')
        .and_then(|(_, u)| u.strip_suffix(']'))
        .unwrap_or("");
    let notes = f.offsets.map_or_else(Vec::new, |o| {
        vec![format!(
            "Series drawn {} {unit} apart so none hides another: read each against the shift its legend entry names.",
            tofprox_format::fmt_num(o.step)
        )]
    });
    let svg = line_chart(&LineChart {
        title: f.title.clone(),
        x_label: f.x_label.clone(),
        y_label: f.y_label.clone(),
        series: f
            .series
            .iter()
            .enumerate()
            .map(|(k, s)| {
                let shift = f.offsets.map(|o| (k / o.every.max(1)) as f64 * o.step);
                figure_series(s, shift, unit)
            })
            .collect(),
        notes,
    });
    tofprox_format::write_atomic(path, svg.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// One figure series as a chart series, drawn `shift` higher (the legend says by how much).
fn figure_series(
    s: &tofprox_model::figures::Series,
    shift: Option<f64>,
    unit: &str,
) -> tofprox_chart::Series {
    use tofprox_chart::Series;
    let (name, points) = match shift {
        Some(dy) if dy != 0.0 => (
            format!("{} (drawn +{} {unit})", s.name, tofprox_format::fmt_num(dy)),
            s.points.iter().map(|(x, y)| (*x, y + dy)).collect(),
        ),
        _ => (s.name.clone(), s.points.clone()),
    };
    if s.markers {
        Series::points(name, points)
    } else {
        Series::line(name, points)
    }
}

fn effects(a: EffectsArgs) -> anyhow::Result<ExitCode> {
    if a.json {
        println!("{}", serde_json::to_string_pretty(catalogue())?);
        return Ok(ExitCode::SUCCESS);
    }
    for e in catalogue() {
        println!(
            "{}  —  {}{}",
            e.id,
            e.title,
            if e.in_baseline { "  [baseline]" } else { "" }
        );
        println!("  thesis: {}", e.thesis_ref);
        println!("  {}", e.explanation);
        println!("  signature: {}", e.signature);
        let drivers: Vec<&str> = e.drivers.iter().map(|d| d.as_str()).collect();
        println!(
            "  acts on: {}; varies with: {}; {}",
            e.acts_on.as_str(),
            if drivers.is_empty() {
                "—".to_string()
            } else {
                drivers.join(", ")
            },
            if e.cancels_in_four_phase {
                "cancels in 4-phase"
            } else {
                "stays in 4-phase"
            }
        );
        for p in e.params {
            println!(
                "    {:<24} {:>10} {:<10} range [{}, {}]  {}",
                p.name, p.typical, p.unit, p.min, p.max, p.doc
            );
        }
        println!();
    }
    Ok(ExitCode::SUCCESS)
}

fn show(a: ShowArgs) -> anyhow::Result<ExitCode> {
    let m = load_model(&a.model)?;
    if a.json {
        let summary = tofprox_model::ModelSummary::of(&m);
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(ExitCode::SUCCESS);
    }
    println!("{}: valid model", a.model.display());
    if let Some(d) = &m.description {
        println!("  {d}");
    }
    for p in tofprox_model::catalogue::SENSOR_PARAMS {
        println!(
            "  sensor.{:<22} {} {}",
            p.name,
            m.param("sensor", p.name).unwrap_or(p.typical),
            p.unit
        );
    }
    for e in catalogue() {
        let on = m.effect(e.id).is_some_and(|s| s.enabled);
        println!("{} {}", if on { "[x]" } else { "[ ]" }, e.id);
        if on {
            for p in e.params {
                println!(
                    "      {:<22} {} {}",
                    p.name,
                    m.param(e.id, p.name).unwrap_or(p.typical),
                    p.unit
                );
            }
            if e.id == tofprox_model::effects::waveform_harmonics::ID.as_str()
                && m.waveforms().is_some()
            {
                println!("      (correlation from measured illumination/modulation waveforms)");
            }
        }
    }
    for u in m.user_effects() {
        println!(
            "[x] {} (user effect: {} response to {}, {})",
            u.name,
            u.acts_on.as_str(),
            u.condition,
            u.acts_on.unit()
        );
        match &u.law {
            tofprox_model::effects::user::UserLaw::Shape { knots_x, knots_y } => {
                println!("      knots_x {knots_x:?}\n      knots_y {knots_y:?}");
            }
            tofprox_model::effects::user::UserLaw::Expression { expression, params } => {
                println!("      {}", expression.text());
                for p in params {
                    println!("      {:<22} {} [{}, {}]", p.name, p.value, p.min, p.max);
                }
            }
        }
        if let Some(p) = &u.provenance {
            println!(
                "      fitted on {} ({}): χ²/dof {:.3} → {:.3}",
                p.recording, p.date, p.chi2_per_dof_before, p.chi2_per_dof_after
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
