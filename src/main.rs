//! The `hslt` command: parses arguments and reports errors as one line, never a panic trace.
//! `--version` also names the native libraries actually loaded and the enabled Cargo features, which
//! is what a bug report against a distribution package needs.

use clap::error::ErrorKind;
use clap::{CommandFactory, FromArgMatches};
use hslt::cli::Cli;
use std::ffi::OsString;

fn main() {
    exit_quietly_on_broken_pipe();
    let cli = parse_args(std::env::args_os().collect());
    match hslt::cli::run(cli) {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}

/// Output piped into a program that stops reading (`hslt error … | head`) ends the command, as it
/// would a C program killed by SIGPIPE (status 141), instead of a panic report: Rust ignores SIGPIPE,
/// so the next `println!` panics with "failed printing to stdout: Broken pipe". Every other panic
/// keeps the default report.
fn exit_quietly_on_broken_pipe() {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message =
            payload.downcast_ref::<String>().map(String::as_str).or(payload.downcast_ref::<&str>().copied());
        if message.is_some_and(|m| m.starts_with("failed printing to stdout") && m.contains("Broken pipe")) {
            std::process::exit(141);
        }
        report(info);
    }));
}

/// clap parsing, with `--version` answered by [`long_version`]. Starting an Embree device just to
/// print a version would slow down every command, so the long text is only built when clap reports
/// that a version was asked for; the second parse then prints the short (`-V`) or long
/// (`--version`) text exactly as clap would.
fn parse_args(args: Vec<OsString>) -> Cli {
    let first = Cli::command().try_get_matches_from(&args);
    let mut matches = match first {
        Ok(matches) => matches,
        Err(e) if e.kind() == ErrorKind::DisplayVersion => {
            // Without clap's `string` feature the text must be 'static; it is built once per process.
            let text: &'static str = Box::leak(long_version().into_boxed_str());
            let mut cmd = Cli::command().long_version(text);
            match cmd.try_get_matches_from_mut(&args) {
                Err(e) => e.exit(),
                // Cannot happen (the same arguments asked for a version), but parse on if it does.
                Ok(matches) => matches,
            }
        }
        Err(e) => e.exit(),
    };
    Cli::from_arg_matches_mut(&mut matches).unwrap_or_else(|e| e.format(&mut Cli::command()).exit())
}

/// `<version>` followed by one line each for Embree, OpenImageIO and the Cargo features.
fn long_version() -> String {
    let oiio = match (hslt::image::oiio_version(), hslt::image::oiio_load_error()) {
        (Some(version), _) => version,
        (None, Some(why)) => format!("unavailable: {why}"),
        (None, None) => "not built in (feature `oiio` off: EXR and PNG only)".to_string(),
    };
    let features: Vec<&str> = [
        ("oiio", cfg!(feature = "oiio")),
        ("embree4", cfg!(feature = "embree4")),
        ("bindgen", cfg!(feature = "bindgen")),
    ]
    .into_iter()
    .filter_map(|(name, on)| on.then_some(name))
    .collect();
    format!(
        "{}\nEmbree {} (loaded at run time)\nOpenImageIO {}\nfeatures: {}",
        env!("CARGO_PKG_VERSION"),
        hslt::accel::embree_version(),
        oiio,
        if features.is_empty() { "(none)".to_string() } else { features.join(", ") }
    )
}
