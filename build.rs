//! With the `mujoco` feature, the binary and the tests find MuJoCo's library where they were
//! linked against it (`MUJOCO_DYNAMIC_LINK_DIR`, the pip wheel's folder): an rpath, so that
//! neither a user nor systemd has to set `LD_LIBRARY_PATH`.

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if std::env::var_os("CARGO_FEATURE_MUJOCO").is_none() {
        return;
    }
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        for kind in ["bins", "tests"] {
            println!("cargo::rustc-link-arg-{kind}=-Wl,-rpath,{dir}");
        }
    }
}
