//! The SLAM pipeline's settings: the relative stage's (`[relative]`) and
//! the absolute stage's (`[absolute]`) tables side by side, so that neither
//! stage owns the other's. `rigslam run --config FILE` reads this file;
//! the daemon has the same two tables under `[slam]`.

use std::path::Path;

use crate::absolute::settings::{AbsoluteSettings, SettingError};
use crate::relative::{ConfigError, RelativeConfig};

/// Both stages' settings; every key has a default.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlamSettings {
    /// `[relative]`: the windowed visual-inertial odometry.
    pub relative: RelativeConfig,
    /// `[absolute]`: the edge map, position filter and recognition (used
    /// with `rigslam run --absolute` or `--load-map`).
    pub absolute: AbsoluteSettings,
}

impl From<SettingError> for ConfigError {
    fn from(e: SettingError) -> Self {
        ConfigError::OutOfRange {
            key: e.key,
            value: e.value,
            allowed: e.allowed,
        }
    }
}

impl SlamSettings {
    /// Reads and checks a settings file; a file that puts the relative
    /// stage's keys at the top level (the layout before the two tables)
    /// is refused with the table to move them to.
    pub fn from_toml_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// [`Self::from_toml_file`] on text; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let settings: Self = toml::from_str(text).map_err(|e| {
            let message = match misplaced_relative_keys(text) {
                Some(keys) => format!(
                    "{} belong to the relative stage: put them under a [relative] table \
                     (the absolute stage's keys go under [absolute])",
                    keys.join(", ")
                ),
                None => e.to_string(),
            };
            ConfigError::Parse {
                path: origin.to_string(),
                message,
            }
        })?;
        settings.validate()?;
        Ok(settings)
    }

    /// The settings as the text of a TOML file with both tables (e.g. to write out the defaults).
    pub fn to_toml(&self) -> Result<String, ConfigError> {
        toml::to_string(self).map_err(|e| ConfigError::Parse {
            path: "(defaults)".into(),
            message: e.to_string(),
        })
    }

    /// Checks every value of both tables against its allowed range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.relative.validate()?;
        self.absolute.to_config()?;
        self.absolute.to_localise_config()?;
        Ok(())
    }
}

/// The top-level keys of `text` that are relative-stage keys, if any.
fn misplaced_relative_keys(text: &str) -> Option<Vec<String>> {
    let table: toml::Table = toml::from_str(text).ok()?;
    let known = toml::Table::try_from(RelativeConfig::default()).ok()?;
    let keys: Vec<String> = table
        .keys()
        .filter(|k| known.contains_key(k.as_str()))
        .map(|k| format!("`{k}`"))
        .collect();
    (!keys.is_empty()).then_some(keys)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_round_trip_through_toml() {
        let text = SlamSettings::default().to_toml().expect("toml");
        assert!(
            text.contains("[relative]") && text.contains("[absolute]"),
            "{text}"
        );
        let back = SlamSettings::from_toml_str(&text, "defaults").expect("parse");
        assert_eq!(back, SlamSettings::default());
    }

    #[test]
    fn held_keyframes_follow_takes_its_three_values() {
        use crate::relative::window::HeldKeyframesFollow;
        for (value, want) in [
            ("in-flight", HeldKeyframesFollow::InFlight),
            ("on", HeldKeyframesFollow::On),
            ("off", HeldKeyframesFollow::Off),
        ] {
            let text = format!("[relative]\ncamera_imu_held_keyframes_follow = \"{value}\"\n");
            let s = SlamSettings::from_toml_str(&text, "t.toml").expect(value);
            assert_eq!(s.relative.camera_imu_held_keyframes_follow, want);
        }
        let e = SlamSettings::from_toml_str(
            "[relative]\ncamera_imu_held_keyframes_follow = \"sometimes\"\n",
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("sometimes") && e.contains("in-flight"), "{e}");
    }

    #[test]
    fn each_table_names_its_bad_key_and_old_layouts_are_told_where_to_go() {
        let err = |text: &str| {
            SlamSettings::from_toml_str(text, "test.toml")
                .unwrap_err()
                .to_string()
        };
        let e = err("[relative]\nwindow_keyframes = 10\nwindow_free = 12\n");
        assert!(e.contains("window_free") && e.contains("1 to"), "{e}");
        let e = err("[relative]\nfeaturs = 100\n");
        assert!(e.contains("featurs"), "{e}");
        for (text, key) in [
            ("imu_noise_scale_gyro = 0.0\n", "noise_scale_gyro"),
            ("imu_noise_scale_accel = -2.0\n", "noise_scale_accel"),
            ("imu_noise_scale_accel = 1000.0\n", "noise_scale_accel"),
            ("imu_noise_adaptation_memory_s = nan\n", "memory_s"),
            ("imu_noise_adaptation_joined_links = 0\n", "joined_links"),
            ("imu_noise_adaptation_joined_links = 40\n", "joined_links"),
            ("level_time_constant_s = -1.0\n", "level_time_constant_s"),
            ("covariance_pixel_gain = 0.0\n", "covariance_pixel_gain"),
            ("covariance_pixel_floor = -0.5\n", "covariance_pixel_floor"),
            ("covariance_pixel_floor = inf\n", "covariance_pixel_floor"),
        ] {
            let e = err(&format!("[relative]\n{text}"));
            assert!(e.contains(key), "{text}: {e}");
        }
        let e = err("[absolute]\npolicy = \"knn:x\"\n");
        assert!(e.contains("absolute.policy"), "{e}");
        let e = err("features = 100\nwindow_keyframes = 10\n");
        assert!(
            e.contains("`features`") && e.contains("[relative]") && e.contains("test.toml"),
            "{e}"
        );
        let e = err("nonsense = 1\n");
        assert!(
            e.contains("nonsense") && !e.contains("[relative] table"),
            "{e}"
        );
        let ok = SlamSettings::from_toml_str(
            "[relative]\nfeatures = 100\n[absolute]\npolicy = \"all\"\n",
            "test.toml",
        )
        .expect("valid");
        assert_eq!(ok.relative.features, 100);
        assert_ne!(ok.absolute, AbsoluteSettings::default());
    }
}
