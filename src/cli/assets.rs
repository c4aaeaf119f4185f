//! Packaging assets generated from the clap definition of the command line: roff man pages
//! (man-pages(7) layout, one page per subcommand as git does) and bash/zsh/fish completions, so the
//! installed documentation can never drift from the parser. Run by `hslt generate-assets DIR`.

use super::Cli;
use anyhow::Context;
use clap::{Args, CommandFactory};
use clap_complete::Shell;
use std::path::{Path, PathBuf};

/// Where the Debian package installs the bundled scenes; named in the man page.
pub const SCENES_DIR: &str = "/usr/share/hslt/scenes";

#[derive(Args, Debug)]
pub struct GenerateAssetsArgs {
    /// Directory to write hslt.1, hslt-<subcommand>.1 and the completion scripts into (created if missing).
    pub dir: PathBuf,
}

/// One generated file: its name inside the asset directory and its contents.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Asset {
    pub file_name: String,
    pub contents: Vec<u8>,
}

/// The shells we ship completions for, with the file name each one's loader looks for
/// (bash-completion loads `completions/<command>`, zsh `_<command>`, fish `<command>.fish`).
pub const SHELLS: [(Shell, &str); 3] =
    [(Shell::Bash, "hslt.bash"), (Shell::Zsh, "_hslt"), (Shell::Fish, "hslt.fish")];

/// The clap command as users see it: hidden subcommands (this generator) are left out, because the
/// completion generators list every subcommand regardless of `hide`; clap's implicit `help`
/// subcommand is left out too, or it would get a man page of its own.
pub fn command() -> clap::Command {
    let full = Cli::command();
    // Names need a 'static str without clap's `string` feature; the test below checks it matches.
    let mut cmd = clap::Command::new("hslt")
        .version(env!("CARGO_PKG_VERSION"))
        .propagate_version(true)
        .subcommand_required(full.is_subcommand_required_set())
        .arg_required_else_help(full.is_arg_required_else_help_set())
        .disable_help_subcommand(true);
    if let Some(about) = full.get_about() {
        cmd = cmd.about(about.clone());
    }
    if let Some(long_about) = full.get_long_about() {
        cmd = cmd.long_about(long_about.clone());
    }
    for arg in full.get_arguments() {
        cmd = cmd.arg(arg.clone());
    }
    cmd = cmd.subcommands(full.get_subcommands().filter(|s| !s.is_hide_set()).cloned());
    cmd.build();
    cmd
}

/// The man page of the top-level command: the clap-generated sections plus FILES and EXAMPLES.
/// No date is written, so the output depends only on the source (reproducible builds).
pub fn man_page(cmd: &clap::Command) -> anyhow::Result<Vec<u8>> {
    let man = clap_mangen::Man::new(cmd.clone());
    let mut out = Vec::new();
    man.render_title(&mut out)?;
    man.render_name_section(&mut out)?;
    man.render_synopsis_section(&mut out)?;
    man.render_description_section(&mut out)?;
    man.render_options_section(&mut out)?;
    man.render_subcommands_section(&mut out)?;
    out.extend_from_slice(extra_sections().as_bytes());
    man.render_version_section(&mut out)?;
    Ok(out)
}

/// Hand-written roff for what clap cannot know: where the example scenes are and how to start.
fn extra_sections() -> String {
    format!(
        ".SH EXAMPLES\n\
         .TP\n\
         \\fBhslt render {SCENES_DIR}/cornell\\-box/scene.xml \\-o cbox.exr \\-o cbox.png\\fR\n\
         Render the bundled Cornell box to an EXR and a PNG with the scene's own sample count.\n\
         .TP\n\
         \\fBhslt render scene.xml \\-o out.png \\-\\-spp 16 \\-D resx=320 \\-D resy=240\\fR\n\
         Override the sample count and scene parameters declared with <default>.\n\
         .TP\n\
         \\fBhslt info scene.xml\\fR\n\
         Describe a scene and the renderer features it needs.\n\
         .SH FILES\n\
         .TP\n\
         \\fI{SCENES_DIR}\\fR\n\
         Example scenes (cornell\\-box, materials, furnace) installed by the Debian package.\n\
         .SH \"SEE ALSO\"\n\
         \\fBhslt\\-render\\fR(1), \\fBhslt\\-info\\fR(1), \\fBhslt\\-bench\\fR(1)\n"
    )
}

/// Every asset `generate-assets` writes: `hslt.1`, one `hslt-<name>.1` per visible subcommand, and
/// the completion scripts of [`SHELLS`].
pub fn assets() -> anyhow::Result<Vec<Asset>> {
    let cmd = command();
    let mut out = vec![Asset { file_name: "hslt.1".to_string(), contents: man_page(&cmd)? }];
    for sub in cmd.get_subcommands() {
        // After `build()`, a subcommand's display name is "hslt-<name>", the conventional page name.
        let man = clap_mangen::Man::new(sub.clone());
        let mut contents = Vec::new();
        man.render(&mut contents)?;
        out.push(Asset { file_name: man.get_filename(), contents });
    }
    for (shell, file_name) in SHELLS {
        out.push(Asset { file_name: file_name.to_string(), contents: completion(shell) });
    }
    Ok(out)
}

/// The completion script for one shell.
pub fn completion(shell: Shell) -> Vec<u8> {
    let mut cmd = command();
    let mut out = Vec::new();
    clap_complete::generate(shell, &mut cmd, "hslt", &mut out);
    out
}

/// Writes [`assets`] into `dir`, returning the paths written.
pub fn write_assets(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut written = Vec::new();
    for asset in assets()? {
        let path = dir.join(&asset.file_name);
        std::fs::write(&path, &asset.contents).with_context(|| format!("cannot write {}", path.display()))?;
        written.push(path);
    }
    // The OpenImageIO shim the binary opens on first use; the package installs it in /usr/lib/hslt/.
    #[cfg(feature = "oiio")]
    {
        let built = crate::image::built_oiio_shim_path();
        let path = dir.join(built.file_name().expect("the shim path names a file"));
        std::fs::copy(built, &path).with_context(|| {
            format!("cannot copy the OpenImageIO shim {} to {}", built.display(), path.display())
        })?;
        written.push(path);
    }
    Ok(written)
}

/// `hslt generate-assets DIR`.
pub fn run(args: GenerateAssetsArgs) -> anyhow::Result<i32> {
    for path in write_assets(&args.dir)? {
        println!("wrote {}", path.display());
    }
    Ok(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_generator_is_left_out_of_pages_and_completions() {
        let assets = assets().unwrap();
        let names: Vec<&str> = assets.iter().map(|a| a.file_name.as_str()).collect();
        assert!(names.contains(&"hslt-render.1"), "{names:?}");
        assert!(!names.iter().any(|n| n.contains("generate")), "{names:?}");
        assert!(!names.contains(&"hslt-help.1"), "{names:?}");
        for asset in &assets {
            let text = String::from_utf8_lossy(&asset.contents);
            assert!(!text.contains("generate-assets"), "{}", asset.file_name);
        }
    }

    #[test]
    fn public_command_keeps_every_visible_subcommand_and_root_argument() {
        let full = Cli::command();
        let public = command();
        assert_eq!(full.get_name(), public.get_name());
        let visible: Vec<&str> =
            full.get_subcommands().filter(|s| !s.is_hide_set()).map(|s| s.get_name()).collect();
        let kept: Vec<&str> = public.get_subcommands().map(|s| s.get_name()).collect();
        assert_eq!(visible, kept);
        for arg in full.get_arguments() {
            assert!(
                public.get_arguments().any(|a| a.get_id() == arg.get_id()),
                "root argument {} lost",
                arg.get_id()
            );
        }
    }
}
