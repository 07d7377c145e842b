//! `base-ros2 --help`.

fn main() -> std::process::ExitCode {
    base_ros2::cli::main(std::env::args_os())
}
