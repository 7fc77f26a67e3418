//! Model bundles and learner checkpoints on disk: tensors in safetensors (readable
//! from Python/numpy), metadata in TOML.
//!
//! A bundle in folder `dir` with stem `model` is `model.toml` plus `model-<hash>.safetensors`,
//! the TOML naming its tensors file with size and FNV-1a hash. Writing puts the tensors file
//! down first (temp file, fsync, rename), then the TOML the same way: at every instant the
//! folder holds one complete bundle, old or new, never half of one. Reading checks size, hash,
//! names, dtypes and shapes, and refuses anything off with an error that says what.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use nalgebra::{DMatrix, DVector};
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};

use softarm_kinematics::poly::Polynomial;
use softarm_kinematics::rbf::RbfNetwork;
use softarm_learning::arm::{Corrected, Sample};
use softarm_learning::cacla::LearnerState;
use softarm_learning::online::ArmState;
use softarm_method::promp::{Basis, Primitive};
use softarm_sections::arm::ArmConfig;
use softarm_sections::learner::LearnerConfig;

/// 2: the polynomial kinematics (`kinematics.weights`) joined the model.
pub const FORMAT: u32 = 2;

#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    #[error("no {what} at {path} (run `softarm train` to make one)")]
    Missing { what: &'static str, path: PathBuf },
    #[error("{path}: {why}")]
    Io { path: PathBuf, why: String },
    #[error("{path} is not a valid bundle: {why}")]
    Invalid { path: PathBuf, why: String },
    #[error(
        "{path} was made for another arm: {bundle}; the config describes {config}. Run `softarm \
         train` on this arm, or point model.dir at a bundle made for it"
    )]
    OtherArm {
        path: PathBuf,
        bundle: String,
        config: String,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> BundleError + '_ {
    move |e| BundleError::Io {
        path: path.to_path_buf(),
        why: e.to_string(),
    }
}

/// FNV-1a, 64 bit: catches truncation and corruption (not tampering).
pub fn fnv64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Writes `bytes` to `path` atomically ([`softarm_runtime::file::write_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), BundleError> {
    softarm_runtime::file::write_atomic(path, bytes, None).map_err(io(path))
}

/// Named tensors on their way to or from a file.
#[derive(Debug, Default)]
pub struct Tensors {
    map: BTreeMap<String, (Dtype, Vec<usize>, Vec<u8>)>,
}

impl Tensors {
    pub fn put_f64(&mut self, name: &str, shape: &[usize], values: &[f64]) {
        debug_assert_eq!(shape.iter().product::<usize>(), values.len());
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.map
            .insert(name.into(), (Dtype::F64, shape.to_vec(), bytes));
    }

    pub fn put_u64(&mut self, name: &str, values: &[u64]) {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.map
            .insert(name.into(), (Dtype::U64, vec![values.len()], bytes));
    }

    pub fn has(&self, name: &str) -> bool {
        self.map.contains_key(name)
    }

    fn get(&self, name: &str, dtype: Dtype) -> Result<(&[usize], &[u8]), String> {
        let (d, shape, bytes) = self
            .map
            .get(name)
            .ok_or_else(|| format!("tensor {name:?} is missing"))?;
        if *d != dtype {
            return Err(format!("tensor {name:?} is {d:?}, expected {dtype:?}"));
        }
        Ok((shape, bytes))
    }

    /// An f64 tensor whose shape must equal `shape` (`None` entries match any length).
    pub fn f64s(
        &self,
        name: &str,
        shape: &[Option<usize>],
    ) -> Result<(Vec<usize>, Vec<f64>), String> {
        let (s, bytes) = self.get(name, Dtype::F64)?;
        let fits =
            s.len() == shape.len() && s.iter().zip(shape).all(|(a, b)| b.is_none_or(|b| *a == b));
        if !fits {
            return Err(format!(
                "tensor {name:?} has shape {s:?}, expected {shape:?}"
            ));
        }
        let v: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(format!("tensor {name:?} holds a non-finite value at {i}"));
        }
        Ok((s.to_vec(), v))
    }

    pub fn u64s(&self, name: &str) -> Result<Vec<u64>, String> {
        let (s, bytes) = self.get(name, Dtype::U64)?;
        if s.len() != 1 {
            return Err(format!(
                "tensor {name:?} has shape {s:?}, expected one axis"
            ));
        }
        Ok(bytes
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect())
    }
}

/// Where a bundle's tensors are and how to know them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TensorsRef {
    pub file: String,
    pub bytes: u64,
    /// FNV-1a 64 of the file, hex.
    pub fnv64: String,
}

/// Writes `<dir>/<stem>.toml` (with `meta` and a `[tensors]` reference) and its tensors file.
pub fn write<M: Serialize>(
    dir: &Path,
    stem: &str,
    meta: &M,
    tensors: &Tensors,
) -> Result<TensorsRef, BundleError> {
    let views: Vec<(String, TensorView<'_>)> = tensors
        .map
        .iter()
        .map(|(name, (d, shape, bytes))| {
            TensorView::new(*d, shape.clone(), bytes).map(|v| (name.clone(), v))
        })
        .collect::<Result<_, _>>()
        .map_err(|e| BundleError::Invalid {
            path: dir.to_path_buf(),
            why: format!("building tensors: {e:?}"),
        })?;
    let data = safetensors::serialize(views, None).map_err(|e| BundleError::Invalid {
        path: dir.to_path_buf(),
        why: format!("serialising tensors: {e:?}"),
    })?;
    let hash = fnv64(&data);
    let file = format!("{stem}-{hash:016x}.safetensors");
    write_atomic(&dir.join(&file), &data)?;
    let reference = TensorsRef {
        file: file.clone(),
        bytes: data.len() as u64,
        fnv64: format!("{hash:016x}"),
    };
    let mut table = toml::Table::try_from(meta).map_err(|e| BundleError::Invalid {
        path: dir.to_path_buf(),
        why: format!("metadata: {e}"),
    })?;
    table.insert(
        "tensors".into(),
        toml::Value::try_from(&reference).expect("a flat struct serialises"),
    );
    let text = format!(
        "# softarm {stem}: metadata; tensors in {file} (safetensors)\n{}",
        toml::to_string(&table).expect("a table serialises")
    );
    let toml_path = dir.join(format!("{stem}.toml"));
    write_atomic(&toml_path, text.as_bytes())?;
    // Older tensors files of this stem are no longer referenced, and the temporary files of a
    // writer killed mid-write (named with its pid) will never be finished: one writer per
    // folder, so whatever is not this process's goes.
    let ours = format!(".{}.tmp", std::process::id());
    if let Ok(entries) = fs::read_dir(dir) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            let old_tensors = name.starts_with(&format!("{stem}-"))
                && name.ends_with(".safetensors")
                && name != file;
            let orphan = (name.starts_with(&format!(".{stem}-"))
                || name.starts_with(&format!(".{stem}.toml.")))
                && name.ends_with(".tmp")
                && !name.ends_with(&ours);
            if old_tensors || orphan {
                let _ = fs::remove_file(e.path());
            }
        }
    }
    Ok(reference)
}

/// Reads `<dir>/<stem>.toml` and its tensors; checks the tensors file against the reference.
pub fn read<M: for<'de> Deserialize<'de>>(
    dir: &Path,
    stem: &str,
    what: &'static str,
) -> Result<(M, Tensors, TensorsRef), BundleError> {
    let toml_path = dir.join(format!("{stem}.toml"));
    let invalid = |why: String| BundleError::Invalid {
        path: toml_path.clone(),
        why,
    };
    let text = match fs::read_to_string(&toml_path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(BundleError::Missing {
                what,
                path: toml_path,
            });
        }
        Err(e) => return Err(io(&toml_path)(e)),
    };
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| invalid(e.to_string()))?;
    let reference: TensorsRef = table
        .remove("tensors")
        .ok_or_else(|| invalid("no [tensors] section".into()))?
        .try_into()
        .map_err(|e: toml::de::Error| invalid(format!("[tensors]: {e}")))?;
    let meta: M = table
        .try_into()
        .map_err(|e: toml::de::Error| invalid(e.to_string()))?;
    if reference.file.contains('/') || reference.file.contains("..") {
        return Err(invalid(format!(
            "tensors file {:?} must be a plain file name",
            reference.file
        )));
    }
    let tpath = dir.join(&reference.file);
    let data = fs::read(&tpath).map_err(|e| BundleError::Invalid {
        path: tpath.clone(),
        why: format!("cannot read the tensors file: {e}"),
    })?;
    let bad_tensors = |why: String| BundleError::Invalid {
        path: tpath.clone(),
        why,
    };
    if data.len() as u64 != reference.bytes {
        return Err(bad_tensors(format!(
            "{} bytes, the metadata says {} (truncated or replaced)",
            data.len(),
            reference.bytes
        )));
    }
    let hash = format!("{:016x}", fnv64(&data));
    if hash != reference.fnv64 {
        return Err(bad_tensors(format!(
            "content hash {hash} differs from the metadata's {} (corrupt)",
            reference.fnv64
        )));
    }
    let st = SafeTensors::deserialize(&data).map_err(|e| bad_tensors(format!("{e:?}")))?;
    let mut tensors = Tensors::default();
    for name in st.names() {
        let v = st
            .tensor(name)
            .map_err(|e| bad_tensors(format!("{name}: {e:?}")))?;
        tensors.map.insert(
            name.to_string(),
            (v.dtype(), v.shape().to_vec(), v.data().to_vec()),
        );
    }
    Ok((meta, tensors, reference))
}

/// Everything training produces: the primitives, the forward model and the pre-trained learner.
/// For an arm of `N` actuators: its actuation primitives have `N` degrees of freedom, its models
/// `N` inputs, its actor `N` outputs. (`N` defaults to six, and [`Model::read`] reads six, only
/// for the rehearsal and the root package's tests `adaptation` and `train_kill`, which name no
/// `N` yet.)
#[derive(Debug, Clone)]
pub struct Model<const N: usize> {
    pub actuation: Vec<Primitive>,
    pub task: Vec<Primitive>,
    pub forward: RbfNetwork<N>,
    /// The polynomial whose Jacobian steers the online corrections.
    pub kinematics: Polynomial<N>,
    pub learner: LearnerState<N>,
    pub demo_duration_s: f64,
    /// The arm it was made for (`softarm_arm::Layout::identity`).
    pub arm: String,
    /// Identity of the bundle it was read from (its tensors hash); empty before writing.
    pub id: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelMeta {
    format: u32,
    kind: String,
    primitives: usize,
    basis_functions: usize,
    basis_width: f64,
    demo_duration_s: f64,
    forward_sigma: f64,
    /// Absent from format 1: defaulted, so the format check can say what is wrong.
    #[serde(default)]
    kinematics_degree: usize,
    /// Absent from bundles written before they named their arm: all were made for the paper's.
    #[serde(default)]
    arm: Option<String>,
    learner: LearnerConfig,
}

fn put_primitive(t: &mut Tensors, name: &str, p: &Primitive) {
    let n = p.weight_mean().len();
    t.put_f64(&format!("{name}.mean"), &[n], p.weight_mean().as_slice());
    // Row-major, as numpy reads it; Σ_w is symmetric anyway.
    let cov = p.weight_cov().transpose();
    t.put_f64(&format!("{name}.cov"), &[n, n], cov.as_slice());
}

fn get_primitive(t: &Tensors, name: &str, basis: &Basis, dofs: usize) -> Result<Primitive, String> {
    let n = basis.len() * dofs;
    let (_, mean) = t.f64s(&format!("{name}.mean"), &[Some(n)])?;
    let (_, cov) = t.f64s(&format!("{name}.cov"), &[Some(n), Some(n)])?;
    Primitive::from_weights(
        basis.clone(),
        dofs,
        DVector::from_vec(mean),
        DMatrix::from_row_slice(n, n, &cov),
    )
    .map_err(|e| format!("{name}: {e}"))
}

fn put_learner<const N: usize>(t: &mut Tensors, s: &LearnerState<N>) {
    let keys: Vec<u64> = s.actor.iter().map(|e| e.0).collect();
    let w: Vec<f64> = s.actor.iter().flat_map(|e| e.1).collect();
    t.put_u64("actor.keys", &keys);
    t.put_f64("actor.weights", &[keys.len(), N], &w);
    let keys: Vec<u64> = s.critic.iter().map(|e| e.0).collect();
    let w: Vec<f64> = s.critic.iter().map(|e| e.1[0]).collect();
    t.put_u64("critic.keys", &keys);
    t.put_f64("critic.weights", &[keys.len()], &w);
}

fn get_learner<const N: usize>(
    t: &Tensors,
    config: LearnerConfig,
) -> Result<LearnerState<N>, String> {
    let keys = t.u64s("actor.keys")?;
    let (_, w) = t.f64s("actor.weights", &[Some(keys.len()), Some(N)])?;
    let actor = keys
        .iter()
        .zip(w.chunks_exact(N))
        .map(|(k, c)| (*k, std::array::from_fn(|i| c[i])))
        .collect();
    let keys = t.u64s("critic.keys")?;
    let (_, w) = t.f64s("critic.weights", &[Some(keys.len())])?;
    let critic = keys.iter().zip(&w).map(|(k, v)| (*k, [*v])).collect();
    // Bundles and checkpoints written before per-point memory moved to the running set hold
    // a "memory" tensor too; it is of a set long gone, and not read.
    Ok(LearnerState {
        config,
        actor,
        critic,
    })
}

impl<const N: usize> Model<N> {
    /// Writes the bundle into `dir` (as `model.toml` + tensors) and returns its id.
    pub fn write(&self, dir: &Path) -> Result<String, BundleError> {
        if self.arm.is_empty() {
            return Err(BundleError::Invalid {
                path: dir.to_path_buf(),
                why: "the model names no arm it was made for".into(),
            });
        }
        let first = &self.actuation[0];
        let (centres, sigma, weights) = self.forward.parts();
        let meta = ModelMeta {
            format: FORMAT,
            kind: "softarm-model".into(),
            primitives: self.actuation.len(),
            basis_functions: first.basis().len(),
            basis_width: first.basis().width(),
            demo_duration_s: self.demo_duration_s,
            forward_sigma: sigma,
            kinematics_degree: self.kinematics.degree(),
            arm: Some(self.arm.clone()),
            learner: self.learner.config,
        };
        let mut t = Tensors::default();
        for (j, p) in self.actuation.iter().enumerate() {
            put_primitive(&mut t, &format!("promp.actuation.{j}"), p);
        }
        for (j, p) in self.task.iter().enumerate() {
            put_primitive(&mut t, &format!("promp.task.{j}"), p);
        }
        let c: Vec<f64> = centres.iter().flatten().copied().collect();
        t.put_f64("forward.centres", &[centres.len(), N], &c);
        let w: Vec<f64> = weights.iter().flatten().copied().collect();
        t.put_f64("forward.weights", &[weights.len(), 3], &w);
        let k = self.kinematics.weights();
        let kw: Vec<f64> = k.iter().flatten().copied().collect();
        t.put_f64("kinematics.weights", &[k.len(), 3], &kw);
        put_learner(&mut t, &self.learner);
        Ok(write(dir, "model", &meta, &t)?.fnv64)
    }

    /// Reads the bundle in `dir` ([`Model::read`]) for the arm `arm`
    /// (`softarm_arm::Layout::identity`): a bundle made for another arm is refused, naming
    /// both.
    /// Before the tensors: a bundle of another arm has other shapes, which are not what is
    /// wrong with it. For an arm of `N` actuators.
    pub fn read_for_arm(dir: &Path, arm: &str) -> Result<Self, BundleError> {
        Self::read_checked(dir, Some(arm))
    }

    /// Reads and checks the bundle of an arm of `N` actuators in `dir`; nothing is
    /// half-loaded.
    pub fn read(dir: &Path) -> Result<Self, BundleError> {
        Self::read_checked(dir, None)
    }

    fn read_checked(dir: &Path, want_arm: Option<&str>) -> Result<Self, BundleError> {
        let (meta, t, reference): (ModelMeta, _, _) = read(dir, "model", "model bundle")?;
        let made_for = meta.arm.clone().unwrap_or_else(default_arm);
        if let Some(want) = want_arm
            && made_for != want
        {
            return Err(BundleError::OtherArm {
                path: dir.to_path_buf(),
                bundle: made_for,
                config: want.to_string(),
            });
        }
        let invalid = |why: String| BundleError::Invalid {
            path: dir.join("model.toml"),
            why,
        };
        if meta.format != FORMAT || meta.kind != "softarm-model" {
            return Err(invalid(format!(
                "format {} of kind {:?}; this softarm reads format {FORMAT} of \"softarm-model\"",
                meta.format, meta.kind
            )));
        }
        if meta.primitives == 0 || meta.primitives > softarm_method::activation::MAX_PRIMITIVES {
            return Err(invalid(format!("{} primitives", meta.primitives)));
        }
        let basis = Basis::new(meta.basis_functions, Some(meta.basis_width))
            .map_err(|e| invalid(e.to_string()))?;
        let build = || -> Result<Model<N>, String> {
            let actuation = (0..meta.primitives)
                .map(|j| get_primitive(&t, &format!("promp.actuation.{j}"), &basis, N))
                .collect::<Result<Vec<_>, _>>()?;
            let task = (0..meta.primitives)
                .map(|j| get_primitive(&t, &format!("promp.task.{j}"), &basis, 3))
                .collect::<Result<Vec<_>, _>>()?;
            let (shape, c) = t.f64s("forward.centres", &[None, Some(N)])?;
            let centres: Vec<[f64; N]> = c
                .chunks_exact(N)
                .map(|r| std::array::from_fn(|i| r[i]))
                .collect();
            let (_, w) = t.f64s("forward.weights", &[Some(shape[0] + N + 1), Some(3)])?;
            let weights: Vec<[f64; 3]> = w.chunks_exact(3).map(|r| [r[0], r[1], r[2]]).collect();
            let forward = RbfNetwork::from_parts(centres, meta.forward_sigma, weights)?;
            let terms = softarm_kinematics::poly::terms(
                N,
                meta.kinematics_degree
                    .min(softarm_sections::kinematics::MAX_DEGREE),
            );
            let (_, kw) = t.f64s("kinematics.weights", &[Some(terms), Some(3)])?;
            let kinematics = Polynomial::from_weights(
                meta.kinematics_degree,
                kw.chunks_exact(3).map(|r| [r[0], r[1], r[2]]).collect(),
            )?;
            meta.learner.validate()?;
            let learner = get_learner(&t, meta.learner)?;
            Ok(Model {
                actuation,
                task,
                forward,
                kinematics,
                learner,
                demo_duration_s: meta.demo_duration_s,
                arm: made_for.clone(),
                id: reference.fnv64.clone(),
            })
        };
        build().map_err(invalid)
    }
}

/// The identity of the default `[arm]` (the paper's arm), which every bundle written before
/// bundles named their arm was made for.
fn default_arm() -> String {
    let layout = ArmConfig::default().layout();
    layout.expect("the default [arm] is valid").identity()
}

/// Watches a bundle folder for a new or changed bundle (after `softarm train`), looking at most
/// every `every`: the controller and the learner each keep one and reload on a change.
#[derive(Debug)]
pub struct BundleWatch {
    dir: PathBuf,
    every: Duration,
    looked: Option<Instant>,
    seen: Option<SystemTime>,
}

impl BundleWatch {
    /// A watch whose first look is due at once, so a bundle already there counts as new.
    pub fn new(dir: PathBuf, every: Duration) -> Self {
        Self {
            dir,
            every,
            looked: None,
            seen: None,
        }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Whether `model.toml` was there at the last look.
    pub fn exists(&self) -> bool {
        self.seen.is_some()
    }

    /// `true` once for every bundle that appeared or changed since the last look; `false` while
    /// nothing changed, nothing is there, or the next look is not due.
    pub fn changed(&mut self) -> bool {
        if self.looked.is_some_and(|t| t.elapsed() < self.every) {
            return false;
        }
        self.looked = Some(Instant::now());
        let stamp = fs::metadata(self.dir.join("model.toml"))
            .and_then(|m| m.modified())
            .ok();
        let changed = stamp.is_some() && stamp != self.seen;
        self.seen = stamp;
        changed
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CheckpointMeta {
    format: u32,
    kind: String,
    /// The model bundle this learner descends from.
    model: String,
    learner: LearnerConfig,
}

/// Saves the learner's state as `<dir>/learner.toml` + tensors.
pub fn write_checkpoint<const N: usize>(
    dir: &Path,
    state: &LearnerState<N>,
    arm: &ArmState<N>,
    model_id: &str,
) -> Result<(), BundleError> {
    let meta = CheckpointMeta {
        format: FORMAT,
        kind: "softarm-learner".into(),
        model: model_id.into(),
        learner: state.config,
    };
    let mut t = Tensors::default();
    put_learner(&mut t, state);
    put_arm(&mut t, arm);
    write(dir, "learner", &meta, &t).map(|_| ())
}

/// A learner checkpoint as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint<const N: usize> {
    pub state: LearnerState<N>,
    /// What the learner knew of the arm (empty from checkpoints written before it was kept).
    pub arm: ArmState<N>,
    /// The id of the model it descends from.
    pub model: String,
}

/// Reads a learner checkpoint of an arm of `N` actuators.
pub fn read_checkpoint<const N: usize>(dir: &Path) -> Result<Checkpoint<N>, BundleError> {
    let (meta, t, _): (CheckpointMeta, _, _) = read(dir, "learner", "learner checkpoint")?;
    let invalid = |why: String| BundleError::Invalid {
        path: dir.join("learner.toml"),
        why,
    };
    if meta.format != FORMAT || meta.kind != "softarm-learner" {
        return Err(invalid(format!(
            "format {} of kind {:?}",
            meta.format, meta.kind
        )));
    }
    meta.learner.validate().map_err(invalid)?;
    let state = get_learner(&t, meta.learner).map_err(invalid)?;
    let arm = get_arm(&t).map_err(|e| invalid(format!("the arm's state: {e}")))?;
    Ok(Checkpoint {
        state,
        arm,
        model: meta.model,
    })
}

fn put_arm<const N: usize>(t: &mut Tensors, arm: &ArmState<N>) {
    let n = arm.corrections.len();
    let targets: Vec<f64> = arm.corrections.iter().flat_map(|c| c.target).collect();
    let estimates: Vec<f64> = arm.corrections.iter().flat_map(|c| c.estimate).collect();
    t.put_f64("arm.corrections.targets", &[n, 3], &targets);
    t.put_f64("arm.corrections.estimates", &[n, N], &estimates);
    let m = arm.footprint.len();
    let stamps: Vec<u64> = arm.footprint.iter().map(|s| s.stamp_ns).collect();
    let counts: Vec<u64> = arm.footprint.iter().map(|s| u64::from(s.count)).collect();
    let actuations: Vec<f64> = arm.footprint.iter().flat_map(|s| s.actuation).collect();
    let positions: Vec<f64> = arm.footprint.iter().flat_map(|s| s.position).collect();
    t.put_u64("arm.footprint.stamps", &stamps);
    t.put_u64("arm.footprint.counts", &counts);
    let settled: Vec<u64> = arm.footprint.iter().map(|s| u64::from(s.settled)).collect();
    t.put_u64("arm.footprint.settled", &settled);
    t.put_f64("arm.footprint.actuations", &[m, N], &actuations);
    t.put_f64("arm.footprint.positions", &[m, 3], &positions);
}

/// The arm's state; none in a checkpoint written before it was kept.
fn get_arm<const N: usize>(t: &Tensors) -> Result<ArmState<N>, String> {
    if !t.has("arm.corrections.targets") {
        return Ok(ArmState::default());
    }
    let (s, targets) = t.f64s("arm.corrections.targets", &[None, Some(3)])?;
    let (_, estimates) = t.f64s("arm.corrections.estimates", &[Some(s[0]), Some(N)])?;
    if let Some(v) = estimates.iter().find(|v| !(0.0..=1.0).contains(*v)) {
        return Err(format!("an estimate of {v} is outside [0, 1]"));
    }
    let corrections = (0..s[0])
        .map(|i| Corrected {
            target: std::array::from_fn(|d| targets[3 * i + d]),
            estimate: std::array::from_fn(|d| estimates[N * i + d]),
        })
        .collect();
    let stamps = t.u64s("arm.footprint.stamps")?;
    let m = Some(stamps.len());
    let counts = t.u64s("arm.footprint.counts")?;
    let (_, actuations) = t.f64s("arm.footprint.actuations", &[m, Some(N)])?;
    let (_, positions) = t.f64s("arm.footprint.positions", &[m, Some(3)])?;
    if counts.len() != stamps.len() {
        return Err(format!(
            "{} footprint counts for {} samples",
            counts.len(),
            stamps.len()
        ));
    }
    // Written before samples of an arm that lags were kept apart: all of them settled.
    let settled = match t.has("arm.footprint.settled") {
        true => t.u64s("arm.footprint.settled")?,
        false => vec![1; stamps.len()],
    };
    if settled.len() != stamps.len() || settled.iter().any(|v| *v > 1) {
        return Err(format!(
            "arm.footprint.settled must be {} flags of 0 or 1",
            stamps.len()
        ));
    }
    if let Some(v) = actuations.iter().find(|v| !(0.0..=1.0).contains(*v)) {
        return Err(format!("a footprint actuation of {v} is outside [0, 1]"));
    }
    let footprint = (0..stamps.len())
        .map(|i| {
            Ok(Sample {
                stamp_ns: stamps[i],
                actuation: std::array::from_fn(|d| actuations[N * i + d]),
                position: std::array::from_fn(|d| positions[3 * i + d]),
                count: u32::try_from(counts[i])
                    .ok()
                    .filter(|c| *c >= 1)
                    .ok_or_else(|| format!("a footprint count of {}", counts[i]))?,
                settled: settled[i] == 1,
            })
        })
        .collect::<Result<_, String>>()?;
    Ok(ArmState {
        corrections,
        footprint,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::{Training, from_plant};
    use softarm_learning::cacla::CaclaMtl;
    use softarm_sections::arm::ArmConfig;
    use softarm_sections::demonstrations::DemoRecipe;
    use softarm_sections::forward_model::NetworkConfig;
    use softarm_sections::learner::PretrainConfig;

    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    /// The default `[arm]`'s identity.
    fn paper() -> String {
        ArmConfig::default().layout().unwrap().identity()
    }

    /// A small model of the default `[arm]` from the pipeline, with one remembered point so
    /// the memory round-trips too.
    fn model() -> Model<N> {
        let recipe = DemoRecipe {
            demos_per_class: 4,
            ..Default::default()
        };
        let training = Training {
            basis_functions: 8,
            forward: NetworkConfig {
                centres: 40,
                ..Default::default()
            },
            kinematics: Default::default(),
            learner: LearnerConfig::default(),
            pretrain: PretrainConfig {
                max_epochs: 20,
                ..Default::default()
            },
            imitation_passes: 0,
        };
        let (mut m, _) =
            from_plant(&ArmConfig::default(), &recipe, 3, &training, |_| true).unwrap();
        let mut l = CaclaMtl::restore(&m.learner).unwrap();
        l.observe(
            &mut None,
            &[0.1, 0.0, -0.45],
            &[0.4; 6],
            &[0.11, 0.0, -0.46],
        );
        m.learner = l.state();
        m.arm = paper();
        m
    }

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("softarm-bundle-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        d
    }

    /// A bundle says which arm it was made for; one for another arm is refused naming both,
    /// one that names none is not written, and one written before bundles named their arm
    /// reads as the paper's.
    #[test]
    fn a_bundle_for_another_arm_is_refused() {
        let mut m = model();
        let dir = tmp("arm");
        m.write(&dir).unwrap();
        let paper = paper();
        assert_eq!(Model::<N>::read_for_arm(&dir, &paper).unwrap().arm, paper);
        let nine = "9 actuators (a1 .. a9) in 3 modules, layout 0";
        let e = Model::<N>::read_for_arm(&dir, nine)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("made for another arm") && e.contains(&paper) && e.contains(nine),
            "{e}"
        );
        // Written before bundles named their arm: the paper's.
        let meta = dir.join("model.toml");
        let text = fs::read_to_string(&meta).unwrap();
        let line = text
            .lines()
            .find(|l| l.starts_with("arm = "))
            .unwrap()
            .to_string();
        fs::write(&meta, text.replace(&format!("{line}\n"), "")).unwrap();
        assert_eq!(Model::<N>::read_for_arm(&dir, &paper).unwrap().arm, paper);
        m.arm.clear();
        let e = m.write(&tmp("noarm")).unwrap_err().to_string();
        assert!(e.contains("names no arm"), "{e}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_bundle_round_trips_exactly() {
        let m = model();
        let dir = tmp("roundtrip");
        let id = m.write(&dir).unwrap();
        let back = Model::<N>::read(&dir).unwrap();
        assert_eq!(back.id, id);
        assert_eq!(back.actuation, m.actuation);
        assert_eq!(back.task, m.task);
        assert_eq!(back.forward, m.forward);
        assert_eq!(back.learner, m.learner);
        // Rewriting leaves one tensors file.
        m.write(&dir).unwrap();
        let n = fs::read_dir(&dir)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .ends_with(".safetensors")
            })
            .count();
        assert_eq!(n, 1);

        // What the learner knew of the arm round-trips with it.
        let arm = ArmState {
            corrections: vec![Corrected {
                target: [0.1, 0.0, -0.45],
                estimate: [0.41, 0.48, 0.6, 0.53, 0.5, 0.44],
            }],
            footprint: vec![
                Sample {
                    stamp_ns: 123_456_789_012,
                    actuation: [0.4, 0.5, 0.6, 0.5, 0.5, 0.45],
                    position: [0.1, 0.01, -0.46],
                    count: 7,
                    settled: true,
                },
                Sample {
                    stamp_ns: 123_456_789_013,
                    actuation: [0.5, 0.5, 0.6, 0.5, 0.5, 0.45],
                    position: [0.11, 0.01, -0.46],
                    count: 1,
                    settled: false,
                },
            ],
        };
        write_checkpoint(&dir, &m.learner, &arm, &id).unwrap();
        let back = read_checkpoint::<N>(&dir).unwrap();
        assert_eq!(
            (back.state, back.arm, back.model),
            (m.learner.clone(), arm.clone(), id.clone())
        );
        // A checkpoint of before the arm's state was kept reads with none.
        let mut t = Tensors::default();
        put_learner(&mut t, &m.learner);
        assert_eq!(get_arm::<6>(&t), Ok(ArmState::default()));
        // A broken one is refused, saying what is wrong.
        let mut broken = arm.clone();
        broken.footprint[0].actuation[2] = 1.5;
        put_arm(&mut t, &broken);
        let e = get_arm::<6>(&t).unwrap_err();
        assert!(e.contains("1.5 is outside [0, 1]"), "{e}");
        // Settled flags that are not one 0 or 1 per sample; none at all reads as settled.
        put_arm(&mut t, &arm);
        t.put_u64("arm.footprint.settled", &[1, 2]);
        let e = get_arm::<6>(&t).unwrap_err();
        assert!(
            e.contains("arm.footprint.settled must be 2 flags of 0 or 1"),
            "{e}"
        );
        t.put_u64("arm.footprint.settled", &[1]);
        assert!(get_arm::<6>(&t).is_err());
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_watch_reports_each_new_bundle_once() {
        let dir = tmp("watch");
        let mut w = BundleWatch::new(dir.clone(), Duration::ZERO);
        assert!(!w.changed() && !w.exists(), "nothing there yet");
        let file = dir.join("model.toml");
        let stamp = |secs: u64| {
            let f = fs::File::options().write(true).open(&file).unwrap();
            f.set_modified(SystemTime::UNIX_EPOCH + Duration::from_secs(secs))
                .unwrap();
        };
        fs::create_dir_all(&dir).unwrap();
        fs::write(&file, "").unwrap();
        stamp(1_000);
        assert!(w.changed() && w.exists(), "a bundle appeared");
        assert!(!w.changed(), "reported once");
        stamp(2_000);
        assert!(w.changed(), "a new bundle");
        let mut slow = BundleWatch::new(dir.clone(), Duration::from_secs(3600));
        assert!(slow.changed(), "the first look is due at once");
        stamp(3_000);
        assert!(!slow.changed(), "the next look is not due yet");
        fs::remove_file(&file).unwrap();
        assert!(!w.changed() && !w.exists(), "gone");
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn corrupt_truncated_or_mismatched_bundles_are_refused() {
        let m = model();
        let dir = tmp("corrupt");
        let r = m.write(&dir).unwrap();
        let tensors = dir.join(format!("model-{r}.safetensors"));
        let good = fs::read(&tensors).unwrap();

        fs::write(&tensors, &good[..good.len() / 2]).unwrap();
        let e = Model::<N>::read(&dir).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");

        let mut flipped = good.clone();
        let i = flipped.len() - 9;
        flipped[i] ^= 0x40;
        fs::write(&tensors, &flipped).unwrap();
        let e = Model::<N>::read(&dir).unwrap_err().to_string();
        assert!(e.contains("corrupt"), "{e}");

        fs::write(&tensors, &good).unwrap();
        let meta = dir.join("model.toml");
        let text = fs::read_to_string(&meta).unwrap();
        fs::write(
            &meta,
            text.replace("basis_functions = 8", "basis_functions = 9"),
        )
        .unwrap();
        let e = Model::<N>::read(&dir).unwrap_err().to_string();
        assert!(e.contains("shape"), "{e}");
        fs::write(&meta, text.replace("format = 2", "format = 7")).unwrap();
        assert!(
            Model::<N>::read(&dir)
                .unwrap_err()
                .to_string()
                .contains("format 7")
        );
        // A bundle an older softarm wrote: the format says so, before any missing field.
        let old = text
            .replace("format = 2", "format = 1")
            .lines()
            .filter(|l| !l.starts_with("kinematics_degree"))
            .collect::<Vec<_>>()
            .join("\n");
        fs::write(&meta, old).unwrap();
        let e = Model::<N>::read(&dir).unwrap_err().to_string();
        assert!(
            e.contains("format 1") && e.contains("reads format 2"),
            "{e}"
        );
        // The polynomial's degree must match its tensor.
        fs::write(
            &meta,
            text.replace("kinematics_degree = 4", "kinematics_degree = 3"),
        )
        .unwrap();
        let e = Model::<N>::read(&dir).unwrap_err().to_string();
        assert!(e.contains("kinematics.weights"), "{e}");
        fs::write(&meta, text.replace("[learner]", "surprise = 1\n[learner]")).unwrap();
        assert!(
            Model::<N>::read(&dir)
                .unwrap_err()
                .to_string()
                .contains("surprise")
        );
        fs::write(&meta, &text).unwrap();
        assert!(Model::<N>::read(&dir).is_ok());

        // Another bundle's tensor file under this bundle's name: whole and well formed, but
        // not the tensors this metadata describes.
        let mut other = model();
        other.demo_duration_s += 1.0;
        other.learner.actor[0].1[0] += 0.01;
        let dir2 = tmp("corrupt-other");
        let r2 = other.write(&dir2).unwrap();
        assert_ne!(r, r2);
        fs::copy(dir2.join(format!("model-{r2}.safetensors")), &tensors).unwrap();
        let e = Model::<N>::read(&dir).unwrap_err().to_string();
        assert!(e.contains("corrupt") || e.contains("size"), "{e}");
        // A model bundle where a learner checkpoint is expected: refused, the file named.
        fs::write(&tensors, &good).unwrap();
        fs::copy(&meta, dir2.join("learner.toml")).unwrap();
        fs::copy(&tensors, dir2.join(format!("model-{r}.safetensors"))).unwrap();
        let e = read_checkpoint::<N>(&dir2).unwrap_err().to_string();
        assert!(e.contains("learner.toml is not a valid bundle"), "{e}");
        fs::remove_dir_all(&dir2).unwrap();

        let e = Model::<N>::read(&dir.join("nowhere"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("softarm train"), "{e}");
        fs::remove_dir_all(&dir).unwrap();
    }
}
