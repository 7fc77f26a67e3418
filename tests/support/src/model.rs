//! A model bundle made in seconds, for the tests, the rehearsal and its examples: the product
//! trains its models through the stack (`softarm train`) or `softarm demo`.

use softarm_config::arm::ArmConfig;
use softarm_config::demonstrations::DemoRecipe;
use softarm_config::forward_model::NetworkConfig;
use softarm_config::learner::{LearnerConfig, PretrainConfig};
use softarm_model::pipeline::{Training, TrainingData, from_plant, train};

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

/// Writes a model bundle of the default `[arm]` made in about two seconds into `dir`
/// (demonstrations straight from its PCC kinematics, as many per class as `softarm train`
/// makes, seed 5, [`quick_training`]); its id. Fewer demonstrations (it had six per class)
/// give primitives so narrow that conditioning them far from their mean, as a changed arm
/// needs, asks for paths the slew limit cannot follow, which no trained model does.
pub fn quick_model(dir: &std::path::Path) -> String {
    let arm = ArmConfig::default();
    let layout = arm.layout().expect("the default [arm]");
    softarm_ipc::with_actuators!(layout.actuators().len(), N => {
        let (mut model, _) =
            from_plant::<N>(&arm, &DemoRecipe::default(), 5, &quick_training(), |_| true)
                .expect("the quick model trains");
        model.arm = layout.identity();
        model.write(dir).expect("the quick model is written")
    }, n => unreachable!("{n} actuators"))
}

/// [`quick_model`] for the arm `config` describes, its demonstrations those the arm's recipe
/// (or the classes derived from the arm) plays through its PCC kinematics; its id.
pub fn quick_model_of(dir: &std::path::Path, config: &softarm_config::Config) -> String {
    let layout = config.layout();
    let plant = softarm_kinematics::pcc::Arm::of_config(&config.arm).expect("a loaded arm");
    softarm_ipc::with_actuators!(layout.actuators().len(), N => {
        let data = TrainingData::<N>::of_arm(&layout, &plant, &config.demonstrations, 5)
            .expect("the arm's demonstrations");
        let (mut model, _) = train(&data, &quick_training(), |_| true)
            .expect("the quick model trains");
        model.arm = layout.identity();
        model.write(dir).expect("the quick model is written")
    }, n => unreachable!("{n} actuators"))
}

#[cfg(test)]
mod tests {
    /// The default `[arm]`'s actuators.
    const N: usize = 6;

    #[test]
    fn the_quick_model_is_written_and_reads_back() {
        let dir =
            std::env::temp_dir().join(format!("softarm-support-quick-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let id = super::quick_model(&dir);
        let m = softarm_model::bundle::Model::<N>::read(&dir).unwrap();
        assert_eq!(m.id, id);
        assert_eq!((m.actuation.len(), m.task.len()), (3, 3));
        assert_eq!(m.forward.centres(), 80);
        // Same inputs, same bundle.
        assert_eq!(super::quick_model(&dir), id);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
