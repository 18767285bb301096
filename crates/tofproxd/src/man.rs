//! The manual page `tofproxd(8)`: the clap definitions (NAME, SYNOPSIS, DESCRIPTION, OPTIONS)
//! and the sections a system daemon's page needs beyond them — CONFIGURATION, D-BUS INTERFACE,
//! FILES, SIGNALS, EXIT STATUS, SEE ALSO.
//!
//! Nothing is written twice: the CONFIGURATION section is derived from the shipped
//! configuration file (`config/tofproxd.toml`, every key with its default and its comment) and
//! the D-BUS INTERFACE section from the shipped introspection XML
//! (`systemd/org.tofprox.Proximity1.xml`, every method, signal and property with its comment),
//! both compiled in, so the page cannot drift from what is installed. Pure: text in, roff out.

use std::fmt::Write as _;

/// The shipped configuration (installed as `/etc/tofprox/tofproxd.toml`).
const SHIPPED_CONFIG: &str = include_str!("../../../config/tofproxd.toml");
/// The shipped introspection XML of the native interface.
const INTERFACE_XML: &str = include_str!("../../../systemd/org.tofprox.Proximity1.xml");

/// The whole page: clap's sections, then ours, then clap's VERSION.
pub fn render(cmd: clap::Command) -> std::io::Result<Vec<u8>> {
    let man = clap_mangen::Man::new(cmd).section("8");
    let mut out = Vec::new();
    man.render_title(&mut out)?;
    man.render_name_section(&mut out)?;
    man.render_synopsis_section(&mut out)?;
    man.render_description_section(&mut out)?;
    man.render_options_section(&mut out)?;
    out.extend_from_slice(extra_sections().as_bytes());
    man.render_version_section(&mut out)?;
    Ok(out)
}

/// The sections beyond clap's, as roff.
pub fn extra_sections() -> String {
    let mut s = String::new();
    s.push_str(&configuration_section(SHIPPED_CONFIG));
    s.push_str(&interface_section(INTERFACE_XML));
    s.push_str(FIXED_SECTIONS);
    s
}

/// Escape text for roff: backslashes, and a leading `.` or `'` that would read as a request.
fn roff_text(line: &str) -> String {
    let t = line.replace('\\', "\\e").replace('-', "\\-");
    if t.starts_with('.') || t.starts_with('\'') {
        format!("\\&{t}")
    } else {
        t
    }
}

/// CONFIGURATION: each `[table]` of the shipped file, and under it each `key = default` with the
/// comment lines above it. Commented-out keys (`# key = value` directly above nothing) are kept
/// in the comment text, as the file shows them.
pub fn configuration_section(toml_text: &str) -> String {
    let mut s = String::from(
        ".SH CONFIGURATION\nThe configuration file is TOML; unknown keys and out-of-range values \
         are errors at start-up, naming the key (\\fB--check-config\\fR runs every check). Each \
         key below with its shipped default:\n",
    );
    let mut comment: Vec<String> = Vec::new();
    let mut table = String::new();
    for raw in toml_text.lines() {
        let line = raw.trim();
        if let Some(c) = line.strip_prefix('#') {
            comment.push(c.trim().to_string());
        } else if line.is_empty() {
            comment.clear();
        } else if line.starts_with('[') {
            table = line.trim_matches(['[', ']']).to_string();
            let _ = writeln!(s, ".SS [{}]", roff_text(&table));
            push_comment(&mut s, &comment);
            comment.clear();
        } else if let Some((key, value)) = line.split_once('=') {
            let key = key.trim();
            let full = if table.is_empty() {
                key.to_string()
            } else {
                format!("{table}.{key}")
            };
            let _ = writeln!(
                s,
                ".TP\n\\fB{}\\fR = {}",
                roff_text(&full),
                roff_text(value.trim())
            );
            push_comment(&mut s, &comment);
            comment.clear();
        }
    }
    s
}

fn push_comment(s: &mut String, comment: &[String]) {
    if !comment.is_empty() {
        let _ = writeln!(s, "{}", roff_text(&comment.join(" ")));
    }
}

/// One member of the interface: its kind, name, signature and comment.
#[derive(Debug, PartialEq)]
pub struct Member {
    /// `method`, `signal` or `property`.
    pub kind: &'static str,
    /// The member's name.
    pub name: String,
    /// The property's type signature (empty for methods and signals).
    pub type_sig: String,
    /// The XML comment above it, whitespace collapsed.
    pub doc: String,
}

/// The members of the first interface of an introspection XML, in file order, each with the
/// comment that precedes it.
pub fn interface_members(xml: &str) -> Vec<Member> {
    let mut out = Vec::new();
    let mut doc = String::new();
    let mut in_comment = false;
    for raw in xml.lines() {
        let line = raw.trim();
        if in_comment || line.starts_with("<!--") {
            let text = line
                .trim_start_matches("<!--")
                .trim_end_matches("-->")
                .trim();
            if !text.is_empty() {
                doc.push_str(if doc.is_empty() { "" } else { " " });
                doc.push_str(text);
            }
            in_comment = !line.ends_with("-->");
            continue;
        }
        for kind in ["method", "signal", "property"] {
            if let Some(rest) = line.strip_prefix(&format!("<{kind} ")) {
                out.push(Member {
                    kind,
                    name: attr(rest, "name").unwrap_or_default(),
                    type_sig: attr(rest, "type").unwrap_or_default(),
                    doc: std::mem::take(&mut doc),
                });
            }
        }
        if line.starts_with("<interface ") && !out.is_empty() {
            break; // a nested interface: only the first is the native one
        }
        if line.starts_with("<interface ") || line.starts_with("<node") {
            doc.clear();
        }
    }
    out
}

fn attr(tag: &str, name: &str) -> Option<String> {
    let start = tag.find(&format!("{name}=\""))? + name.len() + 2;
    let len = tag[start..].find('"')?;
    Some(tag[start..start + len].to_string())
}

/// D-BUS INTERFACE: every method, signal and property of `org.tofprox.Proximity1`.
pub fn interface_section(xml: &str) -> String {
    let mut s = String::from(
        ".SH D-BUS INTERFACE\nBus name and interface \\fBorg.tofprox.Proximity1\\fR at \
         \\fB/org/tofprox/Proximity1\\fR on the system bus (\\fB--bus\\fR). Introspection XML: \
         /usr/share/dbus\\-1/interfaces/org.tofprox.Proximity1.xml.\n",
    );
    for m in interface_members(xml) {
        let head = match m.kind {
            "property" => format!("property \\fB{}\\fR ({})", m.name, m.type_sig),
            kind => format!("{kind} \\fB{}\\fR", m.name),
        };
        let _ = writeln!(s, ".TP\n{head}\n{}", roff_text(&m.doc));
    }
    s
}

/// FILES, SIGNALS, EXIT STATUS, SEE ALSO.
const FIXED_SECTIONS: &str = r#".SH FILES
.TP
/etc/tofprox/tofproxd.toml
The configuration (\fB--config\fR); a conffile of the package.
.TP
/var/lib/tofprox/calib
The module's factory calibration set (\fBprocessing.calibration\fR); made by \fBtofprox calibrate\fR, kept when the package is purged.
.TP
/usr/share/tofprox
The shipped data: configurations, calibration sets of the emulated and example sensors, the example recording.
.TP
/usr/lib/systemd/system/tofproxd.service
The systemd unit (Type=notify, watchdog).
.TP
/usr/share/dbus\-1/system.d/org.tofprox.Proximity1.conf
The system bus policy: who may own the name, claim proximity and claim depth frames (group tofprox\-depth).
.TP
/usr/share/doc/tofprox/docs/daemon.md
The full documentation of the loop, the energy model, the policies and the D\-Bus API.
.SH SIGNALS
.TP
SIGTERM, SIGINT, SIGHUP, SIGQUIT, SIGUSR1, SIGUSR2, SIGALRM
Stop cleanly: the sensor is put into reset, the bus names are released, the unit is told STOPPING=1, and the daemon exits 0. SIGHUP does \fBnot\fR reload the configuration: the daemon stops cleanly (exit 0, so the unit's Restart=on\-failure does not start it again); a new configuration takes effect at the next start (\fBsystemctl restart tofproxd\fR). SIGKILL cannot be caught.
.TP
SIGABRT
Sent by systemd's watchdog when the loop is stuck in one cycle; left at its default action so the hung process is dumped.
.SH EXIT STATUS
.TP
0
Stopped by a signal (clean stop), \fB--check-config\fR passed, or \fB--demo\fR ran to its end.
.TP
2
Any error: the configuration or calibration refused (the message names the file and the key), the frame source could not be opened, the bus could not be reached or the name is owned by another process.
.SH SEE ALSO
\fBtofprox\fR(1), \fBtofprox\-monitor\fR(1), \fBtofprox\-status\fR(1), \fBtofprox\-calibrate\fR(1), \fBsystemd.service\fR(5), \fBbusctl\fR(1), \fBmonitor\-sensor\fR(1)
.PP
/usr/share/doc/tofprox/docs/daemon.md (the loop, the API, the energy model), /usr/share/doc/tofprox/docs/calibration.md (the factory calibration), /usr/share/doc/tofprox/README.md.
"#;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shipped_key_and_member_is_on_the_page() {
        let page = extra_sections();
        // keys of the shipped file, counted independently of the section's parser
        let mut keys = 0;
        let mut table = String::new();
        for line in SHIPPED_CONFIG.lines().map(str::trim) {
            if line.starts_with('[') {
                table = line.trim_matches(['[', ']']).replace('-', "\\-");
            } else if !line.starts_with('#') && line.contains('=') {
                let key = line.split('=').next().unwrap().trim().replace('-', "\\-");
                let full = if table.is_empty() {
                    key
                } else {
                    format!("{table}.{key}")
                };
                assert!(page.contains(&format!("\\fB{full}\\fR")), "{full} missing");
                keys += 1;
            }
        }
        assert!(
            keys > 40,
            "only {keys} keys found in the shipped configuration"
        );
        for name in [
            "ClaimProximity",
            "GetStatus",
            "DepthFrame",
            "Near",
            "NearChangedNs",
        ] {
            assert!(page.contains(&format!("\\fB{name}\\fR")), "{name} missing");
        }
        for section in [
            "FILES",
            "SIGNALS",
            "EXIT STATUS",
            "SEE ALSO",
            "D-BUS INTERFACE",
        ] {
            assert!(
                page.contains(&format!(".SH {section}\n")),
                "{section} missing"
            );
        }
    }

    #[test]
    fn interface_members_carry_their_comment_and_type() {
        let xml = "<node>\n<interface name=\"a.B\">\n<!--\n Says hi\n twice.\n -->\n\
                   <method name=\"Hi\">\n</method>\n<property name=\"N\" type=\"u\" access=\"read\"/>\n\
                   <interface name=\"a.B.C\">\n<method name=\"Other\"/>\n</node>\n";
        let m = interface_members(xml);
        assert_eq!(
            m,
            vec![
                Member {
                    kind: "method",
                    name: "Hi".into(),
                    type_sig: String::new(),
                    doc: "Says hi twice.".into()
                },
                Member {
                    kind: "property",
                    name: "N".into(),
                    type_sig: "u".into(),
                    doc: String::new()
                },
            ]
        );
    }

    #[test]
    fn roff_requests_and_backslashes_are_escaped() {
        assert_eq!(roff_text(".x \\y"), "\\&.x \\ey");
        let s = configuration_section("# one\n# two\nkey = \"a-b\"\n\n[t]\n# c\nk = 1\n");
        assert_eq!(
            s.lines().skip(2).collect::<Vec<_>>(),
            [
                ".TP",
                "\\fBkey\\fR = \"a\\-b\"",
                "one two",
                ".SS [t]",
                ".TP",
                "\\fBt.k\\fR = 1",
                "c"
            ]
        );
    }
}
