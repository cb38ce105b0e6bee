//! The `mcdenoise` command.

#![warn(missing_docs)]

use std::process::ExitCode;

use mcdenoise::runtime::{cleanup, memory};
use mcdenoise::HostError;
use mcdenoise_cli::cli::{self, Command};
use mcdenoise_cli::commands as run;

/// Counts the heap (for `--timings` and the memory tests) and turns a failed
/// allocation into one line and exit 1 instead of an abort.
#[global_allocator]
static ALLOC: memory::CountingAlloc = memory::CountingAlloc;

fn main() -> ExitCode {
    memory::counting_installed();
    // SIGINT / SIGTERM remove the temporary outputs and exit 130 / 143.
    if let Err(e) = cleanup::install_signal_handlers() {
        eprintln!("mcdenoise: error: cannot install the signal handlers: {e}");
        return ExitCode::from(1);
    }
    // A bug must still end in one line, not a backtrace.
    std::panic::set_hook(Box::new(|info| {
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        // Output piped into a reader that stopped (`mcdenoise inspect F |
        // head`): end quietly, as a program killed by SIGPIPE would (141).
        if msg.contains("os error 32") || msg.contains("BrokenPipe") {
            std::process::exit(141);
        }
        let at = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
        eprintln!("mcdenoise: internal error: {msg}{at} (please report this)");
    }));
    let result = match cli::parse(std::env::args_os().skip(1)) {
        Ok(Command::Help(text)) => {
            print!("{text}");
            Ok(())
        }
        Ok(Command::Version(text)) => {
            print!("{text}");
            Ok(())
        }
        Ok(Command::Completions(shell)) => {
            cli::completions(shell, &mut std::io::stdout().lock());
            Ok(())
        }
        Ok(Command::Man { dir }) => cli::man(dir.as_deref(), &mut std::io::stdout().lock()),
        Ok(Command::Demo { settings }) => run::demo(&settings),
        Ok(Command::Denoise(a)) => run::denoise_cmd(&a),
        Ok(Command::Score { reference, output, json }) => run::score_cmd(&reference, &output, json),
        Ok(Command::Inspect { file, selection }) => run::inspect_cmd(&file, &selection),
        Ok(Command::Precision(a)) => mcdenoise_kit::report::run(&a).map(|_| ()),
        Ok(Command::PrecisionMethods { methods, sequence, reference, threads, csv }) => {
            run::precision_methods(&methods, &sequence, reference.as_deref(), threads, &csv)
        }
        Ok(Command::Train(a)) => mcdenoise::train::run(&a),
        Err(e) => Err(e),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e @ HostError::Usage(_)) => {
            eprintln!("mcdenoise: {e}");
            eprintln!("(see 'mcdenoise help' or 'mcdenoise COMMAND --help')");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("mcdenoise: error: {e}");
            ExitCode::from(1)
        }
    }
}
