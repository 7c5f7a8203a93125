//! `mjsafe man` and `mjsafe completions`.

use super::*;

/// How every man page clap_mangen renders starts: an existing file that does not start so is
/// never replaced.
pub(super) const MAN_START: &[u8] = b".ie \\n(.g .ds Aq \\(aq\n";

/// (file name, roff text) of the page of `command` and of each of its subcommands, as
/// `clap_mangen::generate_to` names and renders them.
pub(super) fn man_pages(command: clap::Command) -> std::io::Result<Vec<(String, Vec<u8>)>> {
    fn collect(command: clap::Command, pages: &mut Vec<(String, Vec<u8>)>) -> std::io::Result<()> {
        for sub in command.get_subcommands().filter(|s| !s.is_hide_set()).cloned() {
            collect(sub, pages)?;
        }
        let man = clap_mangen::Man::new(command);
        let mut text = Vec::new();
        man.render(&mut text)?;
        pages.push((man.get_filename(), text));
        Ok(())
    }
    let mut command = command.disable_help_subcommand(true);
    command.build();
    let mut pages = Vec::new();
    collect(command, &mut pages)?;
    Ok(pages)
}

/// `mjsafe man`: the man pages, one per subcommand into `dir`, or the main page on stdout.
pub(super) fn man_command(dir: Option<PathBuf>) -> Result<ExitCode> {
    // `mjsafe help CMD` is `mjsafe CMD --help`: no page of its own, so none listed.
    let mut command = <Cli as clap::CommandFactory>::command();
    command.build();
    let command = command.mut_subcommand("help", |help| help.hide(true));
    match dir {
        Some(dir) => {
            if dir.exists() && !dir.is_dir() {
                bail!(
                    "--dir {}: expected a directory for the man pages, found a file",
                    dir.display()
                );
            }
            let pages = man_pages(command)?;
            // Every page checked before any is written (the files rules: never over a
            // file that is not a man page of mjsafe's, a link or a directory), each
            // written as `.partial` and renamed.
            use crate::files::{check_output, write_atomically, Replace};
            for (name, _) in &pages {
                check_output(&dir.join(name), "man page", Replace::IfStartsWith(MAN_START), &[])?;
            }
            for (name, text) in &pages {
                write_atomically(&dir.join(name), "man page", Replace::IfStartsWith(MAN_START), &[], text)?;
            }
            eprintln!("{} man pages written into {}", pages.len(), dir.display());
        }
        None => {
            let mut text = Vec::new();
            clap_mangen::Man::new(command).render(&mut text)?;
            out!("{}", String::from_utf8_lossy(&text));
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `mjsafe completions`: Print a shell completion script on stdout, e.g.
#[derive(Debug, clap::Args)]
pub struct CompletionsCommand {
    /// The shell.
    shell: clap_complete::Shell,
}

impl CompletionsCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let CompletionsCommand { shell } = self;
        let mut text = Vec::new();
        clap_complete::generate(
            shell,
            &mut <Cli as clap::CommandFactory>::command(),
            "mjsafe",
            &mut text,
        );
        out!("{}", String::from_utf8_lossy(&text));
        Ok(ExitCode::SUCCESS)
    }
}

/// `mjsafe man`: Print the man page (roff) on stdout (`mjsafe man | man -l -`), or write mjsafe.1 and one
#[derive(Debug, clap::Args)]
pub struct ManCommand {
    /// Write the pages into this directory instead.
    #[arg(long, value_name = "DIR")]
    dir: Option<PathBuf>,
}

impl ManCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let ManCommand { dir } = self;
        man_command(dir)
    }
}
