use clap::Parser;

fn main() {
    let cli = leveld::cli::Cli::parse();
    // Logs go to stderr; under systemd the journal adds its own timestamps.
    let filter =
        tracing_subscriber::EnvFilter::try_from_env("LEVELD_LOG").unwrap_or_else(|_| "info".into());
    use std::io::IsTerminal;
    let fmt = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        fmt.without_time().init();
    } else {
        fmt.init();
    }
    match leveld::cli::run(cli) {
        Ok(code) => std::process::exit(code),
        // A reader that stopped early (`leveld man | head`) is no error of leveld's.
        Err(e)
            if e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) =>
        {
            std::process::exit(0)
        }
        Err(e) => {
            eprintln!("leveld: error: {e:#}");
            std::process::exit(2);
        }
    }
}
