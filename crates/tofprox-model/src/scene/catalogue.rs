//! The phone scene catalogue: one row per scene (`PHONE_SCENES`), and [`phone_scenes`] that
//! builds them.

use super::phone::reflectivity;
use super::{CoverWindow, MIN_DISTANCE_M, Motion, PhoneScene, SceneScript, ScriptKind};

/// The scenes a phone meets, with stable names, for near/far thresholds `near_m` /
/// `far_m` (the threshold scenes are placed relative to them; tofproxd's defaults are
/// 0.10 / 0.15 m). Every scene has the typical clean cover window unless its name
/// says `smudged` (crosstalk doubled); ambient light is 0 unless it says `klux`.
/// The catalogue is the table `PHONE_SCENES` (one row per scene).
pub fn phone_scenes(near_m: f64, far_m: f64) -> Vec<PhoneScene> {
    PHONE_SCENES
        .iter()
        .map(|row| row.scene(near_m, far_m))
        .collect()
}

/// What a catalogue scene puts in front of the phone ([`Setup::script`] builds its
/// [`SceneScript`]).
#[derive(Debug, Clone, Copy)]
enum Setup {
    /// Only a wall (or ceiling).
    Wall { distance_m: f64, reflectivity: f64 },
    /// A [`ScriptKind::Band`] at `distance_m` before a dark wall at 6 m.
    Band { distance_m: f64, reflectivity: f64 },
    /// An object coming from 0.6 m to `closest` before a mid-grey wall at 1.5 m; `motion`
    /// unset: the kind's own.
    Object {
        kind: ScriptKind,
        reflectivity: f64,
        closest: Closest,
        motion: Option<Motion>,
    },
    /// A skin face at `distance_m`, swaying ±1 cm.
    FaceAt { distance_m: f64 },
    /// Dark fabric over the whole view sliding down to 1 cm, the fabric behind at 0.5 m.
    Pocket,
    /// Fabric of `reflectivity` over the whole view coming from 0.6 m to 2 cm, pressed on the
    /// cover window, and gone again ([`Motion::Press`], one 20 s period), a mid-grey wall at
    /// 1.5 m before and after.
    PocketPress { reflectivity: f64 },
    /// A table top 4 cm below the axis up to its edge at 0.3 m, a wall at 2 m beyond.
    TableEdge,
}

/// The closest approach of a catalogue object.
#[derive(Debug, Clone, Copy)]
enum Closest {
    /// A distance (m).
    M(f64),
    /// This multiple of the near threshold.
    NearThreshold(f64),
    /// This multiple of the far threshold.
    FarThreshold(f64),
}

/// The cover window of a catalogue scene and the one it was calibrated behind.
#[derive(Debug, Clone, Copy)]
enum Window {
    /// The typical window, clean, calibrated clean.
    Clean,
    /// The typical window smudged ×2 (crosstalk doubled), calibrated clean.
    Smudged,
    /// A strong window (13× the typical one: ≈ the return of a white target at 0.39 m),
    /// calibrated behind it clean.
    Strong,
    /// The strong window smudged ×2, calibrated behind it clean.
    StrongSmudged,
}

/// How long a catalogue scene runs.
#[derive(Debug, Clone, Copy)]
enum Span {
    /// One approach period ([`SceneScript::default`]'s `period_s`).
    Approach,
    /// A static scene: 4 s.
    Static,
    /// A band scene: 12 s, long enough for a false near to count after the far debounce
    /// at the slowest rate.
    Band,
    /// Seconds.
    Seconds(f64),
}

/// One row of the catalogue.
#[derive(Debug, Clone, Copy)]
struct SceneRow {
    name: &'static str,
    description: &'static str,
    setup: Setup,
    ambient_klux: f64,
    window: Window,
    span: Span,
}

impl SceneRow {
    /// The scene of this row for near/far thresholds `near_m` / `far_m`.
    fn scene(&self, near_m: f64, far_m: f64) -> PhoneScene {
        let clean = CoverWindow::default();
        let strong = CoverWindow {
            e_per_us: 13.0 * clean.e_per_us,
            ..clean
        };
        let (cover_window, calibrated_window) = match self.window {
            Window::Clean => (clean, clean),
            Window::Smudged => (CoverWindow::smudged(1.0), clean),
            Window::Strong => (strong, strong),
            Window::StrongSmudged => (
                CoverWindow {
                    smudge_rel: 1.0,
                    ..strong
                },
                strong,
            ),
        };
        let duration_s = match self.span {
            Span::Approach => SceneScript::default().period_s,
            Span::Static => 4.0,
            Span::Band => 12.0,
            Span::Seconds(s) => s,
        };
        PhoneScene {
            name: self.name,
            description: self.description,
            script: self.setup.script(near_m, far_m),
            ambient_klux: self.ambient_klux,
            cover_window,
            calibrated_window,
            duration_s,
        }
    }
}

impl Setup {
    /// The scene's script for near/far thresholds `near_m` / `far_m`.
    fn script(self, near_m: f64, far_m: f64) -> SceneScript {
        let base = SceneScript::default();
        let object = |kind, object_reflectivity, near_m| SceneScript {
            kind,
            object_reflectivity,
            near_m,
            far_m: 0.6,
            wall_distance_m: 1.5,
            wall_reflectivity: 0.5,
            ..base.clone()
        };
        match self {
            Setup::Wall {
                distance_m,
                reflectivity,
            } => SceneScript {
                wall_reflectivity: reflectivity,
                ..SceneScript::wall(distance_m)
            },
            Setup::Band {
                distance_m,
                reflectivity,
            } => SceneScript {
                kind: ScriptKind::Band,
                object_reflectivity: reflectivity,
                near_m: distance_m,
                far_m: distance_m + 0.5,
                wall_distance_m: 6.0,
                wall_reflectivity: reflectivity::DARK_WALL,
                ..base
            },
            Setup::Object {
                kind,
                reflectivity,
                closest,
                motion,
            } => {
                let closest_m = match closest {
                    Closest::M(d) => d,
                    Closest::NearThreshold(k) => k * near_m,
                    Closest::FarThreshold(k) => k * far_m,
                };
                SceneScript {
                    motion,
                    ..object(kind, reflectivity, closest_m)
                }
            }
            Setup::FaceAt { distance_m } => SceneScript {
                face_distance_m: distance_m,
                ..object(ScriptKind::Face, reflectivity::SKIN, 0.05)
            }
            .with_motion(Motion::Sway),
            Setup::Pocket => SceneScript {
                wall_reflectivity: reflectivity::DARK_FABRIC,
                wall_distance_m: 0.5,
                far_m: 0.3,
                ..object(ScriptKind::Plane, reflectivity::DARK_FABRIC, 0.01)
            },
            Setup::PocketPress { reflectivity } => SceneScript {
                period_s: POCKET_PERIOD_S,
                ..object(ScriptKind::Plane, reflectivity, 0.02).with_motion(Motion::Press)
            },
            Setup::TableEdge => SceneScript {
                kind: ScriptKind::TableEdge,
                object_reflectivity: reflectivity::TABLE,
                near_m: 0.04,
                far_m: 0.3,
                wall_distance_m: 2.0,
                wall_reflectivity: 0.5,
                ..base
            },
        }
    }
}

/// The period of a pocket scene: in for 2 s, the fabric pressed on the window for 9 s, out
/// after 18 s.
const POCKET_PERIOD_S: f64 = 20.0;

/// A pocket row: the fabric pressed on the window, no ambient light, the clean window, one
/// pocket period.
const fn pocket_row(name: &'static str, description: &'static str, reflectivity: f64) -> SceneRow {
    SceneRow {
        name,
        description,
        setup: Setup::PocketPress { reflectivity },
        ambient_klux: 0.0,
        window: Window::Clean,
        span: Span::Seconds(POCKET_PERIOD_S),
    }
}

/// A wall (or ceiling) row of the catalogue: no ambient light, the clean window, 4 s.
const fn wall_row(
    name: &'static str,
    description: &'static str,
    distance_m: f64,
    reflectivity: f64,
) -> SceneRow {
    SceneRow {
        name,
        description,
        setup: Setup::Wall {
            distance_m,
            reflectivity,
        },
        ambient_klux: 0.0,
        window: Window::Clean,
        span: Span::Static,
    }
}

/// An object row of the catalogue: no ambient light, the clean window, one approach period.
const fn object_row(
    name: &'static str,
    description: &'static str,
    kind: ScriptKind,
    reflectivity: f64,
    closest: Closest,
    motion: Option<Motion>,
) -> SceneRow {
    SceneRow {
        name,
        description,
        setup: Setup::Object {
            kind,
            reflectivity,
            closest,
            motion,
        },
        ambient_klux: 0.0,
        window: Window::Clean,
        span: Span::Approach,
    }
}

/// A hand approaching to 5 cm, the row's light and window: one approach period.
const fn hand_05cm(
    name: &'static str,
    description: &'static str,
    ambient_klux: f64,
    window: Window,
) -> SceneRow {
    SceneRow {
        ambient_klux,
        window,
        ..object_row(
            name,
            description,
            ScriptKind::Hand,
            reflectivity::SKIN,
            Closest::M(0.05),
            None,
        )
    }
}

/// The catalogue [`phone_scenes`] builds its scenes from, in its order.
const PHONE_SCENES: &[SceneRow] = {
    use Closest::*;
    use ScriptKind::*;
    use reflectivity::*;
    &[
        wall_row(
            "nothing_in_range",
            "nothing within 30 m (open space, sky): no return but the cover window's",
            30.0,
            0.2,
        ),
        wall_row(
            "ceiling_white_030cm",
            "white ceiling at 0.3 m (a low shelf)",
            0.3,
            WHITE,
        ),
        wall_row("ceiling_white_100cm", "white ceiling at 1 m", 1.0, WHITE),
        wall_row(
            "ceiling_white_195cm",
            "white ceiling at 1.95 m, just beyond the unambiguous range c/2f = 1.874 m: its phase wraps to ≈ 8 cm",
            1.95,
            WHITE,
        ),
        wall_row(
            "ceiling_white_250cm",
            "white ceiling at 2.5 m (wraps to ≈ 63 cm)",
            2.5,
            WHITE,
        ),
        wall_row(
            "wall_white_380cm",
            "white wall at 3.8 m, just beyond twice the range (wraps to ≈ 5 cm)",
            3.8,
            WHITE,
        ),
        wall_row(
            "wall_white_400cm",
            "white wall at 4 m (wraps to ≈ 25 cm, weak)",
            4.0,
            WHITE,
        ),
        SceneRow {
            setup: Setup::Band {
                distance_m: 1.90,
                reflectivity: RETROREFLECTIVE_TAPE,
            },
            span: Span::Band,
            ..wall_row(
                "retroreflector_tape_190cm",
                "retroreflective tape (1000× a white wall) over a third of the ROI at 1.90 m, just beyond the unambiguous range: wraps to ≈ 3 cm as bright as a hand, saturates at the second frequency at the start exposure",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 1.95,
                reflectivity: RETROREFLECTIVE_TAPE,
            },
            span: Span::Band,
            ..wall_row(
                "retroreflector_tape_195cm",
                "retroreflective tape (1000×) over a third of the ROI at 1.95 m (wraps to ≈ 8 cm)",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 3.80,
                reflectivity: RETROREFLECTIVE_TAPE,
            },
            span: Span::Band,
            ..wall_row(
                "retroreflector_tape_380cm",
                "retroreflective tape (1000×) over a third of the ROI at 3.8 m, just beyond twice the range (wraps to ≈ 5 cm)",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 1.92,
                reflectivity: SAFETY_VEST,
            },
            span: Span::Band,
            ..wall_row(
                "safety_vest_192cm",
                "a safety vest (30× a white wall) over a third of the ROI at 1.92 m (wraps to ≈ 5 cm)",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::Band {
                distance_m: 3.80,
                reflectivity: SAFETY_VEST,
            },
            span: Span::Band,
            ..wall_row(
                "safety_vest_380cm",
                "a safety vest (30×) over a third of the ROI at 3.8 m",
                0.0,
                0.0,
            )
        },
        wall_row(
            "ceiling_dark_030cm",
            "dark ceiling at 0.3 m",
            0.3,
            DARK_WALL,
        ),
        wall_row("wall_dark_100cm", "dark wall at 1 m", 1.0, DARK_WALL),
        wall_row(
            "ceiling_dark_195cm",
            "dark ceiling at 1.95 m (wraps, weak: the window crosstalk dominates)",
            1.95,
            DARK_WALL,
        ),
        wall_row(
            "wall_dark_400cm",
            "dark wall at 4 m (weaker than the window crosstalk)",
            4.0,
            DARK_WALL,
        ),
        hand_05cm(
            "hand_approach_05cm",
            "a hand approaching to 5 cm and leaving",
            0.0,
            Window::Clean,
        ),
        object_row(
            "hand_approach_03cm_saturating",
            "a hand approaching to 3 cm: the ROI saturates",
            Hand,
            SKIN,
            M(0.03),
            None,
        ),
        object_row(
            "face_dark_hair_02cm",
            "a head with dark hair (6 %) approaching to 2 cm (a call, hair against the sensor)",
            Face,
            DARK_HAIR,
            M(0.02),
            Some(Motion::Approach),
        ),
        object_row(
            "face_dark_hair_05cm",
            "a head with dark hair (6 %) approaching to 5 cm",
            Face,
            DARK_HAIR,
            M(0.05),
            Some(Motion::Approach),
        ),
        SceneRow {
            setup: Setup::FaceAt { distance_m: 0.2 },
            span: Span::Static,
            ..wall_row(
                "face_20cm",
                "a face at 20 cm, swaying ±1 cm (reading the screen up close): far",
                0.0,
                0.0,
            )
        },
        SceneRow {
            setup: Setup::FaceAt { distance_m: 0.3 },
            span: Span::Static,
            ..wall_row(
                "face_30cm",
                "a face at 30 cm, swaying ±1 cm (reading the screen): far",
                0.0,
                0.0,
            )
        },
        object_row(
            "black_card_02cm",
            "a black card (5 %) approaching to 2 cm",
            Card,
            BLACK_CARD,
            M(0.02),
            None,
        ),
        object_row(
            "black_card_05cm",
            "a black card (5 %) approaching to 5 cm",
            Card,
            BLACK_CARD,
            M(0.05),
            None,
        ),
        SceneRow {
            span: Span::Seconds(10.0),
            ..object_row(
                "cheek_pressed_10s",
                "a cheek pressed on the window for 10 s (a call): every code saturates even at the shortest exposure",
                Plane,
                SKIN,
                M(MIN_DISTANCE_M),
                Some(Motion::Static),
            )
        },
        object_row(
            "finger_third_of_field_04cm",
            "a finger approaching to 4 cm upright across the axis: it covers a third of the field's width (two thirds of the ROI)",
            Finger,
            SKIN,
            M(0.04),
            None,
        ),
        object_row(
            "grey_card_near_threshold",
            "an 18 % grey card approaching to 0.9 × the near threshold: switches to near",
            Card,
            GREY_CARD,
            NearThreshold(0.9),
            None,
        ),
        SceneRow {
            span: Span::Static,
            ..object_row(
                "grey_card_beyond_far",
                "an 18 % grey card held at 1.2 × the far threshold: stays far",
                Card,
                GREY_CARD,
                FarThreshold(1.2),
                Some(Motion::Static),
            )
        },
        SceneRow {
            setup: Setup::Pocket,
            ..hand_05cm(
                "pocket",
                "sliding into a pocket: dark fabric (10 %) over the whole view down to 1 cm, everything dark",
                0.0,
                Window::Clean,
            )
        },
        pocket_row(
            "pocket_dark_fabric",
            "into a pocket and out: a dark lining (3 %) over the whole view to 2 cm, pressed on the window for 9 s (its return at the window's phase, 1.7× the window's), then the room again",
            DARK_LINING,
        ),
        pocket_row(
            "pocket_light_fabric",
            "into a pocket and out: light fabric (50 %) over the whole view to 2 cm, pressed on the window for 9 s (12.5× the window's return, at its phase), then the room again",
            LIGHT_FABRIC,
        ),
        SceneRow {
            setup: Setup::TableEdge,
            ..wall_row(
                "table_edge",
                "standing in a stand at a table's edge: the table top 4 cm below the axis at grazing incidence (≥ 18 cm in the ROI) up to its edge at 0.3 m, a wall at 2 m beyond",
                0.0,
                0.0,
            )
        },
        SceneRow {
            span: Span::Static,
            ..object_row(
                "swipe_fast",
                "a hand swiping across the view at 5 cm with 1.5 m/s (≈ 0.1 s in view)",
                Hand,
                SKIN,
                M(0.05),
                Some(Motion::Swipe),
            )
        },
        SceneRow {
            ambient_klux: 30.0,
            ..wall_row(
                "sunlight_far_30klux",
                "30 klux of sunlight on a far scene (grass/ground at 1.2 m)",
                1.2,
                0.3,
            )
        },
        SceneRow {
            ambient_klux: 100.0,
            ..wall_row(
                "sunlight_far_100klux",
                "100 klux of direct sunlight on a far scene (ground at 1.2 m)",
                1.2,
                0.3,
            )
        },
        hand_05cm(
            "sunlight_hand_30klux",
            "a hand approaching to 5 cm in 30 klux",
            30.0,
            Window::Clean,
        ),
        hand_05cm(
            "sunlight_hand_100klux",
            "a hand approaching to 5 cm in 100 klux of direct sunlight",
            100.0,
            Window::Clean,
        ),
        SceneRow {
            window: Window::Smudged,
            ..wall_row(
                "window_smudged_nothing_in_range",
                "smudged cover window (crosstalk doubled after calibration), nothing in range",
                30.0,
                0.2,
            )
        },
        SceneRow {
            window: Window::Smudged,
            ..wall_row(
                "window_smudged_ceiling_195cm",
                "smudged cover window, white ceiling at 1.95 m",
                1.95,
                WHITE,
            )
        },
        hand_05cm(
            "window_smudged_hand_approach_05cm",
            "smudged cover window, a hand approaching to 5 cm",
            0.0,
            Window::Smudged,
        ),
        hand_05cm(
            "window_strong_hand_approach_05cm",
            "a strong cover window (13× typical) calibrated behind it, a hand approaching to 5 cm",
            0.0,
            Window::Strong,
        ),
        SceneRow {
            window: Window::StrongSmudged,
            ..object_row(
                "window_strong_smudged_dark_hair_05cm",
                "the strong window (13× typical, calibrated clean) smudged ×2, a head with dark hair (6 %) approaching to 5 cm and leaving",
                Face,
                DARK_HAIR,
                M(0.05),
                Some(Motion::Approach),
            )
        },
        SceneRow {
            window: Window::Smudged,
            ..object_row(
                "window_smudged_black_card_05cm",
                "smudged cover window, a black card approaching to 5 cm",
                Card,
                BLACK_CARD,
                M(0.05),
                None,
            )
        },
    ]
};
