//! Log set-up and error printing shared by the `tofproxd` and `tofprox` binaries.
use std::io::IsTerminal as _;

/// Colour in log output only when it goes to a terminal and `NO_COLOR`
/// (<https://no-color.org>: set and not empty) is not set: redirected stderr
/// and the journal get plain text.
pub fn colour_wanted(stderr_is_terminal: bool, no_color: Option<&std::ffi::OsStr>) -> bool {
    stderr_is_terminal && no_color.is_none_or(|v| v.is_empty())
}

/// Log to stderr with `RUST_LOG` if set, else `default_filter` (e.g. `"info"`);
/// colour per [`colour_wanted`]. A second call (a subscriber is already
/// installed) changes nothing.
pub fn init_logging(default_filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    let ansi = colour_wanted(
        std::io::stderr().is_terminal(),
        std::env::var_os("NO_COLOR").as_deref(),
    );
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(ansi)
        .with_writer(std::io::stderr)
        .try_init();
}

/// The one error printer of both binaries (and of the Python package's exceptions).
pub use tofprox_core::error_line;

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Layer(String, Option<Box<dyn std::error::Error + 'static>>);
    impl std::fmt::Display for Layer {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str(&self.0)
        }
    }
    impl std::error::Error for Layer {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            self.1.as_deref()
        }
    }

    #[test]
    fn causes_are_printed_once() {
        let io = std::io::Error::from(std::io::ErrorKind::NotFound);
        let io_text = io.to_string();
        // a library error that prints its source, wrapped in a context that does too
        let lib = Layer(
            format!("cannot read config /x.toml: {io_text}"),
            Some(Box::new(io)),
        );
        let top = Layer(format!("loading: {lib}"), Some(Box::new(lib)));
        let line = error_line(&top);
        assert_eq!(line.matches(&io_text).count(), 1, "{line}");
        assert_eq!(
            line,
            format!("loading: cannot read config /x.toml: {io_text}")
        );
        // distinct causes are all kept, in order
        let chain = Layer("a".into(), Some(Box::new(Layer("b".into(), None))));
        assert_eq!(error_line(&chain), "a: b");
    }

    #[test]
    fn colour_only_on_a_terminal_without_no_color() {
        assert!(colour_wanted(true, None));
        assert!(!colour_wanted(false, None));
        assert!(!colour_wanted(true, Some(std::ffi::OsStr::new("1"))));
        assert!(colour_wanted(true, Some(std::ffi::OsStr::new(""))));
    }
}
