use clap::Parser;

fn main() {
    let cli = leveld::cli::Cli::parse();
    match leveld::cli::run(cli) {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("leveld: error: {e:#}");
            std::process::exit(2);
        }
    }
}
