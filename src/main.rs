fn main() -> std::process::ExitCode {
    mjsafe::cli::run()
}
