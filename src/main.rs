//! `softarm`, the product: every process and client of the stack, and what `softarm install`
//! installs. Without the test rig (`softarm-rig`, `src/rig.rs`): decision 0014.

fn main() -> std::process::ExitCode {
    softarm::main()
}
