//! Editing a loaded scenario, as the viewer does: changes go to a draft, and the draft becomes the scenario in
//! use only if it passes the same validation as a file ([`Scenario::checked`]); otherwise the last good scenario
//! stays in use and the validator's message is kept for display. Saving writes TOML that loads back to the same
//! scenario. No window and no Bevy here.

use std::path::{Path, PathBuf};

use glam::DVec3;

use super::trajectory::TrajectorySpec;
use super::{CheckedScenario, FieldError, Scenario, TargetSpec};

/// A scenario being edited.
#[derive(Debug, Clone)]
pub struct Session {
    /// The scenario in use: the last draft that passed validation.
    pub applied: CheckedScenario,
    /// What the controls change.
    pub draft: Scenario,
    /// Why the draft was refused, if it was.
    pub error: Option<FieldError>,
    /// Counts the changes of `applied` (a front end rebuilds its simulation when it changes).
    pub revision: u64,
    /// The last refused draft (not validated again while unchanged).
    refused: Option<Scenario>,
}

impl Session {
    /// Starts editing `scenario`.
    pub fn new(scenario: CheckedScenario) -> Self {
        Self { draft: scenario.spec.clone(), applied: scenario, error: None, revision: 0, refused: None }
    }

    /// Validates the draft: if it passes and differs from the scenario in use, it becomes that scenario
    /// (`Ok(true)`); an unchanged draft is `Ok(false)`. A refused draft leaves the scenario in use unchanged and
    /// its error in [`Session::error`].
    ///
    /// # Errors
    /// The validator's [`FieldError`].
    pub fn commit(&mut self) -> Result<bool, FieldError> {
        if self.draft == self.applied.spec {
            self.error = None;
            return Ok(false);
        }
        if let (Some(refused), Some(e)) = (&self.refused, &self.error)
            && *refused == self.draft
        {
            return Err(e.clone());
        }
        match self.draft.clone().checked(&self.applied.source) {
            Ok(checked) => {
                self.applied = checked;
                self.error = None;
                self.revision += 1;
                Ok(true)
            }
            Err(e) => {
                self.error = Some(e.clone());
                self.refused = Some(self.draft.clone());
                Err(e)
            }
        }
    }

    /// Applies `change` to the draft and commits it.
    ///
    /// # Errors
    /// As [`Session::commit`].
    pub fn edit(&mut self, change: impl FnOnce(&mut Scenario)) -> Result<bool, FieldError> {
        change(&mut self.draft);
        self.commit()
    }

    /// Throws the draft's uncommitted changes away.
    pub fn revert(&mut self) {
        self.draft = self.applied.spec.clone();
        self.error = None;
    }

    /// Adds a target flying at constant `velocity_m_s` that passes through `point_m` at time `t_s`, with the
    /// `template`'s body and skin (or a small drone's), named `added_N`; returns its index.
    ///
    /// # Errors
    /// As [`Session::commit`] (the new target is not added then).
    pub fn add_target(
        &mut self,
        point_m: DVec3,
        t_s: f64,
        velocity_m_s: DVec3,
        template: Option<&TargetSpec>,
    ) -> Result<usize, FieldError> {
        let name = (1..)
            .map(|i| format!("added_{i}"))
            .find(|n| self.draft.targets.iter().all(|t| &t.name != n))
            .unwrap_or_default();
        let trajectory = TrajectorySpec::ConstantVelocity { position_m: point_m - velocity_m_s * t_s, velocity_m_s };
        let target = match template {
            Some(t) => TargetSpec { name, trajectory, ..t.clone() },
            None => TargetSpec {
                name,
                trajectory,
                semi_axes_m: DVec3::new(0.3, 0.3, 0.1),
                mach: None,
                emissivity: 0.8,
                heating_k: 10.0,
                brdf: Default::default(),
                reflection: Default::default(),
                attitude: None,
            },
        };
        let before = self.draft.clone();
        self.draft.targets.push(target);
        match self.commit() {
            Ok(_) => Ok(self.draft.targets.len() - 1),
            Err(e) => {
                self.draft = before;
                Err(e)
            }
        }
    }

    /// Removes target `index` (the observer may not track it: the validator says so).
    ///
    /// # Errors
    /// As [`Session::commit`] (the target stays then).
    pub fn remove_target(&mut self, index: usize) -> Result<(), FieldError> {
        if index >= self.draft.targets.len() {
            return Ok(());
        }
        let before = self.draft.clone();
        self.draft.targets.remove(index);
        self.commit().map(|_| ()).inspect_err(|_| self.draft = before)
    }

    /// The scenario in use as TOML, its relative paths rewritten to resolve from `path`'s directory.
    ///
    /// # Errors
    /// If the scenario cannot be written as TOML (it always can: the message names the field otherwise).
    pub fn to_toml(&self, path: &Path) -> Result<String, String> {
        let mut spec = self.applied.spec.clone();
        let dir = |p: &Path| p.parent().map(Path::to_path_buf).unwrap_or_default();
        spec.rebase_paths(&dir(&self.applied.source), &dir(path));
        toml::to_string_pretty(&spec).map_err(|e| format!("the scenario cannot be written as TOML: {e}"))
    }

    /// Saves the scenario in use to `path` (TOML); an existing file is replaced only with `overwrite`. The file
    /// is written whole or not at all.
    ///
    /// # Errors
    /// The reason, naming the file.
    pub fn save(&self, path: &Path, overwrite: bool) -> Result<PathBuf, String> {
        if path.as_os_str().is_empty() {
            return Err("no file name given".into());
        }
        if path.extension().is_none_or(|e| e != "toml") {
            return Err(format!("{}: a scenario is saved as TOML: give the name a .toml extension", path.display()));
        }
        if path.exists() && !overwrite {
            return Err(format!("{} exists: tick 'overwrite' to replace it", path.display()));
        }
        let text = self.to_toml(path)?;
        let header = format!(
            "# {} — saved by irsim {} from {}\n",
            self.applied.spec.name,
            env!("CARGO_PKG_VERSION"),
            self.applied.source.display()
        );
        crate::record::write_atomic(path, format!("{header}{text}").as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(path.to_path_buf())
    }
}

/// Moves a trajectory up by `dz_m` (every kind but a CSV file's, which is `false`).
pub fn shift_altitude(trajectory: &mut TrajectorySpec, dz_m: f64) -> bool {
    match trajectory {
        TrajectorySpec::Polynomial { z_m, .. } => {
            if z_m.is_empty() {
                z_m.push(0.0);
            }
            z_m[0] += dz_m;
        }
        TrajectorySpec::ConstantVelocity { position_m, .. } => position_m.z += dz_m,
        TrajectorySpec::Waypoints { points } => points.iter_mut().for_each(|p| p[3] += dz_m),
        TrajectorySpec::CoordinatedTurn { center_m, .. } => center_m.z += dz_m,
        TrajectorySpec::Csv { .. } => return false,
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn session() -> Session {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/sense_and_avoid.toml");
        Session::new(crate::scenario::load(&path).expect("shipped scenario loads"))
    }

    #[test]
    fn a_bad_edit_keeps_the_scenario_in_use_and_names_the_field() {
        let mut s = session();
        let before = s.applied.spec.clone();
        let e = s.edit(|d| d.targets[0].emissivity = 1.5).unwrap_err();
        assert_eq!(e.path, "targets[0].emissivity", "{e:?}");
        assert_eq!(s.applied.spec, before);
        assert_eq!(s.revision, 0);
        assert!(s.error.is_some());
        // fixing the draft clears the error and applies
        assert_eq!(s.edit(|d| d.targets[0].emissivity = 0.5), Ok(true));
        assert_eq!(s.applied.spec.targets[0].emissivity, 0.5);
        assert!(s.error.is_none());
        assert_eq!(s.revision, 1);
    }

    #[test]
    fn targets_are_added_through_a_point_and_removed() {
        let mut s = session();
        let n = s.applied.spec.targets.len();
        let p = DVec3::new(100.0, 2000.0, 500.0);
        let v = DVec3::new(20.0, 0.0, 0.0);
        let i = s.add_target(p, 3.0, v, None).expect("valid target");
        assert_eq!(s.applied.spec.targets.len(), n + 1);
        let (at, _) = s.applied.target_trajectories[i].state(3.0);
        assert!((at - p).length() < 1e-9, "passes through the point at t = 3 s: {at}");
        assert_eq!(s.applied.spec.targets[i].name, "added_1");
        s.remove_target(i).expect("removable");
        assert_eq!(s.applied.spec.targets.len(), n);
        // out of the world: refused, nothing added
        let far = DVec3::new(1e12, 0.0, 0.0);
        assert!(s.add_target(far, 0.0, v, None).is_err());
        assert_eq!(s.draft.targets.len(), n);
    }

    #[test]
    fn altitude_shifts_every_kind_but_csv() {
        let mut cv = TrajectorySpec::ConstantVelocity { position_m: DVec3::ZERO, velocity_m_s: DVec3::X };
        assert!(shift_altitude(&mut cv, 50.0));
        assert!(matches!(cv, TrajectorySpec::ConstantVelocity { position_m, .. } if position_m.z == 50.0));
        let mut csv = TrajectorySpec::Csv { path: "a.csv".into() };
        assert!(!shift_altitude(&mut csv, 50.0));
    }
}
