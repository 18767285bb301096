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
use rand::SeedableRng;
use rand::rngs::SmallRng;
use rayon::prelude::*;
use tofprox_format::{CaptureSpec, RawFrames, Recording, RecordingWriter};
use tofprox_model::figures::Figure;
use tofprox_model::{
    CaptureRequest, ModelConfig, Scene, SceneScript, SensorGeometry, Simulator, catalogue,
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
    }
}

/// Parse `FROM:TO:STEP` or a comma list of distances.
fn parse_distances(s: &str) -> anyhow::Result<Vec<f64>> {
    let bad = || format!("--distances `{s}`: expected FROM:TO:STEP or a comma list of metres");
    let v: Vec<f64> = if s.contains(':') {
        let parts: Vec<f64> = s
            .split(':')
            .map(|p| p.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(bad)?;
        let [from, to, step] = parts[..] else {
            bail!(bad())
        };
        if !(step.is_finite() && step > 0.0 && from.is_finite() && to.is_finite() && to >= from) {
            bail!("{}: need STEP > 0 and TO ≥ FROM", bad());
        }
        let n = ((to - from) / step + 1e-9).floor() as usize;
        if n > 100_000 {
            bail!("--distances `{s}` gives {} points, at most 100000", n + 1);
        }
        (0..=n).map(|i| from + step * i as f64).collect()
    } else {
        s.split(',')
            .map(|p| p.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(bad)?
    };
    if v.is_empty() {
        bail!(bad());
    }
    Ok(v)
}

fn phases_for(n: usize) -> anyhow::Result<Vec<f64>> {
    Ok(match n {
        2 => vec![0.0, 90.0],
        4 => vec![0.0, 90.0, 180.0, 270.0],
        24 => (0..24).map(|k| 15.0 * k as f64).collect(),
        other => bail!("--phases {other}: allowed 2, 4 or 24"),
    })
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

/// Noise seed of capture `index`: independent of scheduling, so the output is the
/// same for any thread count.
fn capture_rng(seed: u64, index: usize) -> SmallRng {
    let mut z = seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    SmallRng::seed_from_u64(z ^ (z >> 31))
}

struct Planned {
    req: CaptureRequest,
    scene: Scene,
    conditions: Vec<(&'static str, f64)>,
    /// Conditions copied from a recording (`sweep --like`) that are no model input.
    copied: Vec<(String, f64)>,
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

/// Simulate `plan` in parallel (chunks, in order) and append every capture.
fn simulate_into(
    sim: &Simulator,
    plan: &[Planned],
    seed: u64,
    writer: &mut RecordingWriter,
    pb: &ProgressBar,
) -> anyhow::Result<()> {
    let chunk = (rayon::current_num_threads() * 8).max(8);
    for (ci, block) in plan.chunks(chunk).enumerate() {
        let base = ci * chunk;
        let frames: Vec<anyhow::Result<RawFrames>> = block
            .par_iter()
            .enumerate()
            .map(|(j, p)| {
                let mut rng = capture_rng(seed, base + j);
                if p.req.averaged == 1
                    && sim.model().is_enabled(tofprox_model::ids::quantization::ID)
                {
                    Ok(RawFrames::U16(sim.capture_u16(&p.scene, &p.req, &mut rng)?))
                } else {
                    Ok(RawFrames::F32(
                        sim.capture(&p.scene, &p.req, &mut rng)?.mapv(|v| v as f32),
                    ))
                }
            })
            .collect();
        for (p, f) in block.iter().zip(frames) {
            let f = f?;
            let spec = CaptureSpec {
                phases_deg: p.req.phases_deg.clone(),
                exposure_us: p.req.exposure_us,
                illumination: p.req.illumination,
                averaged: p.req.averaged,
                timestamp_ns: None,
                conditions: p
                    .conditions
                    .iter()
                    .map(|(k, v)| (k.to_string(), *v))
                    .chain(p.copied.iter().cloned())
                    .collect(),
            };
            writer.append(spec, &f)?;
            pb.inc(1);
        }
    }
    Ok(())
}

fn load_model(path: &Path) -> anyhow::Result<ModelConfig> {
    Ok(ModelConfig::load(path)?)
}

/// The conditions of a recorded capture that the model takes as inputs.
const MODEL_INPUTS: &[&str] = &[
    "distance_m",
    "reflectivity",
    "ambient_klux",
    "temperature_c",
];

/// The plan of `sweep --like`: every capture of `rec` under its own
/// conditions. Returns the plan, the conditions copied but not simulated
/// (by name) and the illuminated captures skipped for want of a distance.
fn plan_like(rec: &Recording) -> anyhow::Result<(Vec<Planned>, Vec<String>, usize)> {
    let mut plan = Vec::new();
    let mut ignored = std::collections::BTreeSet::new();
    let mut skipped = 0;
    for (i, meta) in rec.captures().iter().enumerate() {
        let cond = |k: &str| meta.conditions.get(k).copied();
        let distance = cond("distance_m");
        if meta.illumination && distance.is_none() {
            skipped += 1;
            continue;
        }
        let refl = cond("reflectivity").unwrap_or(1.0);
        let req = CaptureRequest {
            phases_deg: meta.phases_deg.clone(),
            exposure_us: meta.exposure_us,
            illumination: meta.illumination,
            averaged: meta.averaged,
            ambient_klux: cond("ambient_klux").unwrap_or(0.0),
            // the model's default temperature when the recording states none
            temperature_c: cond("temperature_c").unwrap_or(25.0),
        };
        req.validate()
            .with_context(|| format!("{}: capture {i}", rec.dir().display()))?;
        // a dark capture sees no target; the wall only sets the geometry
        let scene = Scene::wall(distance.unwrap_or(1.0), refl);
        scene
            .validate()
            .with_context(|| format!("{}: capture {i}", rec.dir().display()))?;
        let conditions = MODEL_INPUTS
            .iter()
            .filter_map(|k| cond(k).map(|v| (*k, v)))
            .collect();
        let copied = meta
            .conditions
            .iter()
            .filter(|(k, _)| !MODEL_INPUTS.contains(&k.as_str()))
            .map(|(k, v)| (k.clone(), *v))
            .collect::<Vec<_>>();
        ignored.extend(copied.iter().map(|(k, _)| k.clone()));
        plan.push(Planned {
            copied,
            req,
            scene,
            conditions,
        });
    }
    if plan.is_empty() {
        bail!(
            "{}: no capture to simulate (illuminated captures need distance_m)",
            rec.dir().display()
        );
    }
    Ok((plan, ignored.into_iter().collect(), skipped))
}

/// `sim sweep --like REC`: the recording's own conditions through the model.
fn sweep_like(a: &SweepArgs, like: &Path) -> anyhow::Result<ExitCode> {
    let model = load_model(&a.model)?;
    let rec = Recording::open(like)
        .with_context(|| format!("cannot open recording {}", like.display()))?;
    let geometry = *rec.sensor();
    let (plan, ignored, skipped) = plan_like(&rec)?;
    let sim = Simulator::new(&model, geometry, a.seed)?;
    let description = format!(
        "tofprox sim sweep --like {}: model {} (effects: {}), seed {}",
        like.display(),
        a.model.display(),
        model.enabled_effects().join(", "),
        a.seed
    );
    let mut writer = super::new_recording(&a.out, geometry, Some(description), a.force)?;
    let pb = progress(plan.len(), "sweep --like");
    simulate_into(&sim, &plan, a.seed, &mut writer, &pb)?;
    pb.finish_and_clear();
    if !ignored.is_empty() {
        eprintln!(
            "conditions copied but not simulated (no model input): {}",
            ignored.join(", ")
        );
    }
    if skipped > 0 {
        eprintln!("skipped {skipped} illuminated captures without distance_m");
    }
    eprintln!(
        "wrote {} captures like {} to {}",
        writer.len(),
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
    let distances = parse_distances(&a.distances)?;
    let phases = phases_for(a.phases)?;
    let geometry = geometry_for(&a.window)?;
    if a.exposures.is_empty() || a.ambient.is_empty() || a.temperatures.is_empty() {
        bail!("--exposures, --ambient and --temperatures need at least one value");
    }
    if a.repeats == 0 || a.repeats > 10_000 {
        bail!("--repeats {}: allowed 1..=10000", a.repeats);
    }
    let sim = Simulator::new(&model, geometry, a.seed)?;
    let refl = a.reflectivity;
    let mut plan = Vec::new();
    let request = |ph: &[f64], t: f64, illum: bool, amb: f64, temp: f64| CaptureRequest {
        phases_deg: ph.to_vec(),
        exposure_us: t,
        illumination: illum,
        averaged: a.averaged,
        ambient_klux: amb,
        temperature_c: temp,
    };
    // 1. dark frames per exposure and temperature (offset/FPN extraction, 2.3.1.3)
    for &temp in &a.temperatures {
        for &t in &a.exposures {
            plan.push(Planned {
                copied: Vec::new(),
                req: request(&phases, t, false, 0.0, temp),
                scene: Scene::wall(a.correlation_distance, refl),
                conditions: vec![("ambient_klux", 0.0), ("temperature_c", temp)],
            });
        }
    }
    // 2. a 24-phase correlation capture at a known distance (3.3.6)
    let corr_phases = phases_for(24)?;
    let (t0, temp0) = (a.exposures[0], a.temperatures[0]);
    plan.push(Planned {
        copied: Vec::new(),
        req: request(&corr_phases, t0, true, 0.0, temp0),
        scene: Scene::wall(a.correlation_distance, refl),
        conditions: vec![
            ("distance_m", a.correlation_distance),
            ("reflectivity", refl),
            ("ambient_klux", 0.0),
            ("temperature_c", temp0),
        ],
    });
    // 3. the sweeps
    for &temp in &a.temperatures {
        for &amb in &a.ambient {
            for &t in &a.exposures {
                for &d in &distances {
                    for rep in 0..a.repeats {
                        plan.push(Planned {
                            copied: Vec::new(),
                            req: request(&phases, t, true, amb, temp),
                            scene: Scene::wall(d, refl),
                            conditions: vec![
                                ("distance_m", d),
                                ("reflectivity", refl),
                                ("ambient_klux", amb),
                                ("temperature_c", temp),
                                ("repeat", f64::from(rep)),
                            ],
                        });
                    }
                }
            }
        }
    }
    // validate everything before writing anything
    for p in &plan {
        p.req.validate()?;
        p.scene.validate()?;
    }
    let description = format!(
        "tofprox sim sweep: model {} (effects: {}), seed {}",
        a.model.display(),
        model.enabled_effects().join(", "),
        a.seed
    );
    let mut writer = super::new_recording(&a.out, geometry, Some(description), a.force)?;
    let pb = progress(plan.len(), "sweep");
    simulate_into(&sim, &plan, a.seed, &mut writer, &pb)?;
    pb.finish_and_clear();
    eprintln!("wrote {} captures to {}", writer.len(), a.out.display());
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
    let phases = phases_for(a.phases)?;
    if a.phases == 24 {
        bail!("--phases for scenes: 2 or 4");
    }
    let geometry = geometry_for(&a.window)?;
    let sim = Simulator::new(&model, geometry, a.seed)?;
    let plan: Vec<Planned> = (0..n)
        .map(|i| {
            let t = i as f64 / a.rate;
            let mut req = CaptureRequest::with_phases(phases.clone(), a.exposure_us);
            req.averaged = 1;
            Planned {
                copied: Vec::new(),
                req,
                scene: script.at(t),
                conditions: vec![
                    ("distance_m", script.centre_distance_m(t)),
                    (
                        "reflectivity",
                        if script.object_distance_m(t).is_some() {
                            script.object_reflectivity
                        } else {
                            script.wall_reflectivity
                        },
                    ),
                    ("ambient_klux", 0.0),
                    ("temperature_c", 25.0),
                    ("time_s", t),
                ],
            }
        })
        .collect();
    for p in &plan {
        p.req.validate()?;
    }
    let description = format!(
        "tofprox sim scene: {:?} script, model {}, seed {}",
        script.kind,
        a.model.display(),
        a.seed
    );
    let mut writer = super::new_recording(&a.out, geometry, Some(description), a.force)?;
    let pb = progress(plan.len(), "scene");
    simulate_into(&sim, &plan, a.seed, &mut writer, &pb)?;
    pb.finish_and_clear();
    eprintln!("wrote {} frames to {}", writer.len(), a.out.display());
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
        let mut effects = serde_json::Map::new();
        for e in catalogue() {
            let mut params = serde_json::Map::new();
            for p in e.params {
                if let Some(v) = m.param(e.id, p.name) {
                    params.insert(p.name.to_string(), serde_json::json!(v));
                }
            }
            effects.insert(
                e.id.to_string(),
                serde_json::json!({"enabled": m.effect(e.id).is_some_and(|s| s.enabled), "params": params}),
            );
        }
        let sensor: serde_json::Map<String, serde_json::Value> =
            tofprox_model::catalogue::SENSOR_PARAMS
                .iter()
                .filter_map(|p| {
                    m.param("sensor", p.name)
                        .map(|v| (p.name.to_string(), serde_json::json!(v)))
                })
                .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "description": m.description,
                "sensor": sensor,
                "effects": effects,
                "measured_waveforms": m.waveforms().is_some(),
            }))?
        );
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
            if e.id == tofprox_model::ids::waveform_harmonics::ID.as_str()
                && m.waveforms().is_some()
            {
                println!("      (correlation from measured illumination/modulation waveforms)");
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
