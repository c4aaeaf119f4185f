//! The `hslt` command: parses arguments and reports errors as one line, never a panic trace.
//! `--version` also names the native libraries actually loaded and the enabled Cargo features, which
//! is what a bug report against a distribution package needs.

use clap::error::ErrorKind;
use clap::{CommandFactory, FromArgMatches};
use hslt::cli::Cli;
use std::ffi::OsString;

fn main() {
    let cli = parse_args(std::env::args_os().collect());
    match hslt::cli::run(cli) {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
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
    let oiio = hslt::image::oiio_version()
        .unwrap_or_else(|| "not built in (feature `oiio` off: EXR and PNG only)".to_string());
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
