//! The `hslt` command: parses arguments and reports errors as one line, never a panic trace.

use clap::Parser;

fn main() {
    let cli = hslt::cli::Cli::parse();
    match hslt::cli::run(cli) {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}
