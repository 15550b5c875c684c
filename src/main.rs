//! The `star` binary: a thin shell over [`star::cli`].

fn main() -> std::process::ExitCode {
    star::cli::main()
}
