//! `infraloc man --out DIR` (hidden): the manual pages, `DIR/man1/infraloc.1` generated from the
//! clap definitions, so that it cannot drift from `--help`, and `DIR/man5/infraloc.toml.5`, kept
//! by hand in `man/man5/` and checked against the config structs by `tests/man_pages.rs`. The
//! repository's `man/` is this command's output (the same test compares them); the .deb ships it.

use crate::error::{Error, Result};
use clap::CommandFactory;
use std::path::{Path, PathBuf};

/// Arguments of `man`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Directory to write `man1/infraloc.1` and `man5/infraloc.toml.5` into (a MANPATH entry).
    #[arg(long)]
    pub out: PathBuf,
}

/// The configuration page, kept by hand beside the generated one.
const CONFIG_PAGE: &str = include_str!("../../man/man5/infraloc.toml.5");

/// After the generated sections: what clap does not know.
const TAIL: &str = r#".SH "EXIT STATUS"
.TP
.B 0
Success.
.TP
.B 1
Failure, with one line on standard error naming the file, field, device or stage at fault.
.B demo
also exits 1 when its result is farther from the truth than its thresholds.
.TP
.B 3
.BR status :
the service is degraded (it serves an older pose).
.TP
.B 4
.BR status :
no pose is served and the last attempt failed.
.TP
.B 78
The configuration is unusable (EX_CONFIG); each problem is one line naming its key.
.SH FILES
.TP
.I /etc/infraloc/infraloc.toml
The configuration, see
.BR infraloc.toml (5).
.TP
.I /var/lib/infraloc/pose.json
The pose file (schema infraloc.pose.v1) the detection pipeline reads, replaced atomically.
.TP
.I /run/infraloc/control.sock
The service's control socket, used by
.BR status ,
.BR relocalize ,
.B pose
and
.BR overlay .
.SH "SEE ALSO"
.BR infraloc.toml (5),
.BR systemctl (1),
.BR journalctl (1)
.PP
The units
.IR infraloc.service ,
.I infraloc\-relocalize.service
and
.IR infraloc\-relocalize.timer ;
the guides in
.IR /usr/share/doc/infraloc/ .
"#;

/// `infraloc.1`: clap_mangen's title, name, synopsis, description and options, then one
/// subsection per command (nested ones as `plot mi-surface`) with its synopsis,
/// description and options, then exit status, files and see-also.
pub fn infraloc_1() -> Result<String> {
    let mut cmd = super::Cli::command();
    cmd.build();
    let man = clap_mangen::Man::new(cmd.clone()).manual("infraloc manual");
    let mut out = Vec::new();
    let io = |e: std::io::Error| Error::output("man page", e);
    man.render_title(&mut out).map_err(io)?;
    man.render_name_section(&mut out).map_err(io)?;
    man.render_synopsis_section(&mut out).map_err(io)?;
    man.render_description_section(&mut out).map_err(io)?;
    man.render_options_section(&mut out).map_err(io)?;
    // Not clap_mangen's SUBCOMMANDS list: it points at one page per command (infraloc-demo(1)),
    // and this page holds them all.
    let mut text = String::from_utf8(out).map_err(|e| Error::Encode(e.into()))?;
    text.push_str(".SH COMMANDS\n");
    for sub in leaf_commands(&cmd) {
        text.push_str(&command_section(sub)?);
    }
    text.push_str(TAIL);
    Ok(text)
}

/// Every visible command that runs something (not a group like `plot`, not clap's own `help`),
/// in definition order.
pub fn leaf_commands(cmd: &clap::Command) -> Vec<&clap::Command> {
    let mut v = Vec::new();
    for s in cmd
        .get_subcommands()
        .filter(|s| !s.is_hide_set() && s.get_name() != "help")
    {
        if s.has_subcommands() {
            v.extend(leaf_commands(s));
        } else {
            v.push(s);
        }
    }
    v
}

/// One command as a `.SS` subsection: the `.SH` headings clap_mangen writes become plain
/// paragraphs inside it.
fn command_section(sub: &clap::Command) -> Result<String> {
    let name = sub.get_bin_name().unwrap_or(sub.get_name());
    let man = clap_mangen::Man::new(sub.clone());
    let mut out = Vec::new();
    let io = |e: std::io::Error| Error::output(format!("man page {name}"), e);
    man.render_synopsis_section(&mut out).map_err(io)?;
    man.render_description_section(&mut out).map_err(io)?;
    man.render_options_section(&mut out).map_err(io)?;
    let body = String::from_utf8(out).map_err(|e| Error::Encode(e.into()))?;
    let mut s = format!(".SS \"{name}\"\n");
    for line in body.lines() {
        if line.starts_with(".SH ") {
            s.push_str(".PP\n");
        } else {
            s.push_str(line);
            s.push('\n');
        }
    }
    Ok(s)
}

/// Write both pages under `out` (`man1/`, `man5/`).
pub(crate) fn run(a: Args) -> Result<()> {
    write(&a.out.join("man1/infraloc.1"), &infraloc_1()?)?;
    write(&a.out.join("man5/infraloc.toml.5"), CONFIG_PAGE)?;
    Ok(())
}

fn write(path: &Path, text: &str) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}
