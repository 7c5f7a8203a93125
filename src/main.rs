#![deny(unsafe_code)]

fn main() -> std::process::ExitCode {
    mjsafe::cli::run()
}
