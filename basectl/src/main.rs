//! `basectl --help`: the commissioning CLI; everything lives in the library.

fn main() -> std::process::ExitCode {
    basectl::cli::main(std::env::args_os())
}
