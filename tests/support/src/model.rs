//! A model bundle in a second or two: the offline pipeline on demonstrations straight from the
//! kinematic model.

use std::path::Path;

use softarm_method::cacla::{LearnerConfig, PretrainConfig};
use softarm_method::pcc::ArmGeometry;
use softarm_method::rbf::NetworkConfig;
use softarm_method::skill::DemoRecipe;
use softarm_model::pipeline::{self, Training};

/// Quick settings: K = 15, 80 centres, two imitation passes, 300 epochs of pre-training.
pub fn quick_training() -> Training {
    Training {
        basis_functions: 15,
        forward: NetworkConfig {
            centres: 80,
            ..Default::default()
        },
        kinematics: Default::default(),
        learner: LearnerConfig::default(),
        pretrain: PretrainConfig {
            max_epochs: 300,
            ..Default::default()
        },
        imitation_passes: 2,
    }
}

/// Writes a quick model bundle (six demonstrations per class, seed 5) into `dir`; its id.
pub fn quick_model(dir: &Path) -> String {
    let recipe = DemoRecipe {
        demos_per_class: 6,
        ..Default::default()
    };
    let (model, _) = pipeline::from_plant(
        &ArmGeometry::default(),
        &recipe,
        5,
        &quick_training(),
        |_| true,
    )
    .expect("the quick model trains");
    model.write(dir).expect("the quick model is written")
}

#[cfg(test)]
mod tests {
    use super::*;
    use softarm_model::bundle::Model;

    #[test]
    fn the_quick_model_is_written_and_reads_back() {
        let dir =
            std::env::temp_dir().join(format!("softarm-support-quick-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let id = quick_model(&dir);
        let m = Model::read(&dir).unwrap();
        assert_eq!(m.id, id);
        assert_eq!((m.actuation.len(), m.task.len()), (3, 3));
        assert_eq!(m.forward.centres(), 80);
        // Same inputs, same bundle.
        assert_eq!(quick_model(&dir), id);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
