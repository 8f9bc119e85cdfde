//! `subpixel`: render, denoise and measure from the command line.

fn main() -> std::process::ExitCode {
    subpixel::cli::main()
}
