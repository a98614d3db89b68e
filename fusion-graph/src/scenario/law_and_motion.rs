//! `[observation]` and `[dynamics]`: what every sensor measures and how the
//! target moves. Each names its kind, cqnet's own or one the program
//! brought (`kind = "range"`), beside the kind's own parameters; the kind
//! reads and checks them, naming the full key of a bad one.

use bounds::dynamics::{CoordinatedTurn, Motion};
use bounds::observation::{Law, SensorLaw};
use serde::{Deserialize, Serialize};

use crate::params::Params;
use crate::vocabulary::Vocabulary;

/// `[observation]`: the law every sensor measures by, as the file gave it
/// and as built.
#[derive(Clone)]
pub struct ObservationConfig {
    /// The table as read, `kind` included: what the scenario writes back.
    spec: toml::Table,
    law: Law,
    /// cqnet's own law as the file spells it, whose parameters the
    /// scenario's validation checks; `None` for a program's, which
    /// checked its own as it was built.
    built_in: Option<SensorLaw>,
}

/// `[dynamics]`: the target's motion model, as the file gave it and as
/// built.
#[derive(Clone)]
pub struct DynamicsConfig {
    spec: toml::Table,
    /// The sampling period T, seconds: every model has one, and the clock
    /// of a run steps by it.
    pub period: f64,
    motion: Motion,
}

impl ObservationConfig {
    /// `[observation]` as a table, read in `vocabulary` and checked: for
    /// a caller that holds a law's table outside a scenario (the Python
    /// package). The error names the key.
    pub fn read(spec: toml::Table, vocabulary: Vocabulary) -> Result<Self, String> {
        let config = resolve_observation(spec, vocabulary)?;
        if let Some(law) = config.built_in() {
            law.validate().map_err(|e| {
                format!(
                    "`observation.{}`: expected {}, got {}",
                    e.parameter, e.expected, e.value
                )
            })?;
        }
        Ok(config)
    }

    /// The table as the file gave it, `kind` included.
    pub fn table(&self) -> &toml::Table {
        &self.spec
    }

    /// The law, cqnet's own or the program's.
    pub fn law(&self) -> &Law {
        &self.law
    }

    /// The law's name, as `kind` spells it.
    pub fn kind(&self) -> &'static str {
        self.law.name()
    }

    /// cqnet's own law as the file spells it, to check its parameters;
    /// `None` for a program's, which checked its own as it was built.
    pub(crate) fn built_in(&self) -> Option<SensorLaw> {
        self.built_in
    }
}

impl DynamicsConfig {
    /// `[dynamics]` as a table, read in `vocabulary` and checked, with
    /// what every step needs of it computed. The error names the key.
    pub fn read(
        spec: toml::Table,
        vocabulary: Vocabulary,
    ) -> Result<(Self, bounds::Dynamics), String> {
        let config = resolve_dynamics(spec, vocabulary)?;
        let dynamics = match config.turn() {
            Some(turn) => bounds::Dynamics::new(*turn).map_err(|e| {
                format!(
                    "`dynamics.{}`: expected {}, got {}",
                    e.parameter, e.expected, e.value
                )
            })?,
            None => bounds::Dynamics::of(config.motion.clone())
                .map_err(|e| format!("`dynamics`: {e}"))?,
        };
        Ok((config, dynamics))
    }

    /// The table as the file gave it, `kind` included.
    pub fn table(&self) -> &toml::Table {
        &self.spec
    }

    /// The motion model, cqnet's own or the program's.
    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// The model's name, as `kind` spells it (`"coordinated_turn"` when
    /// the file gives none).
    pub fn kind(&self) -> &'static str {
        self.motion.name()
    }

    /// The coordinated turn's parameters, when that is the model.
    pub fn turn(&self) -> Option<&CoordinatedTurn> {
        self.motion.downcast_ref::<CoordinatedTurn>()
    }
}

impl From<CoordinatedTurn> for DynamicsConfig {
    fn from(turn: CoordinatedTurn) -> Self {
        let spec = match toml::Value::try_from(turn) {
            Ok(toml::Value::Table(t)) => t,
            _ => unreachable!("the coordinated turn serializes to a table"),
        };
        Self {
            spec,
            period: turn.period,
            motion: turn.into(),
        }
    }
}

/// The names a `kind` could have been, for an error.
fn one_of(names: impl Iterator<Item = &'static str>) -> String {
    names
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// `kind`, and the rest of the table.
fn split_kind(
    mut table: toml::Table,
    section: &str,
) -> Result<(Option<String>, toml::Table), String> {
    match table.remove("kind") {
        None => Ok((None, table)),
        Some(toml::Value::String(kind)) => Ok((Some(kind), table)),
        Some(other) => Err(format!("`{section}.kind`: expected a string, got {other}")),
    }
}

fn resolve_observation(
    spec: toml::Table,
    vocabulary: Vocabulary,
) -> Result<ObservationConfig, String> {
    let (kind, params) = split_kind(spec.clone(), "observation")?;
    let Some(kind) = kind else {
        return Err("`observation.kind`: missing".into());
    };
    if SensorLaw::KINDS.contains(&kind.as_str()) {
        let law = SensorLaw::deserialize(toml::Value::Table(spec.clone()))
            .map_err(|e| format!("`observation`: {}", e.message()))?;
        return Ok(ObservationConfig {
            spec,
            law: law.into(),
            built_in: Some(law),
        });
    }
    let Some(part) = vocabulary.law(&kind) else {
        let names = SensorLaw::KINDS.into_iter().chain(vocabulary.law_names());
        return Err(format!(
            "`observation.kind`: unknown observation law `{kind}`, expected one of {}",
            one_of(names)
        ));
    };
    let law = part
        .build
        .build(&Params::new("observation", &params))
        .map_err(|e| e.to_string())?;
    Ok(ObservationConfig {
        spec,
        law,
        built_in: None,
    })
}

fn resolve_dynamics(spec: toml::Table, vocabulary: Vocabulary) -> Result<DynamicsConfig, String> {
    let (kind, mut params) = split_kind(spec.clone(), "dynamics")?;
    match kind.as_deref() {
        None | Some(CoordinatedTurn::KIND) => {
            let turn = CoordinatedTurn::deserialize(toml::Value::Table(params))
                .map_err(|e| format!("`dynamics`: {}", e.message()))?;
            Ok(DynamicsConfig {
                spec,
                period: turn.period,
                motion: turn.into(),
            })
        }
        Some(kind) => {
            let Some(part) = vocabulary.motion(kind) else {
                let names = [CoordinatedTurn::KIND]
                    .into_iter()
                    .chain(vocabulary.motion_names());
                return Err(format!(
                    "`dynamics.kind`: unknown motion model `{kind}`, expected one of {}",
                    one_of(names)
                ));
            };
            let period = match params.remove("period") {
                Some(toml::Value::Float(p)) if p.is_finite() && p > 0.0 => p,
                Some(toml::Value::Integer(p)) if p > 0 => p as f64,
                Some(other) => {
                    return Err(format!(
                        "`dynamics.period`: expected a finite number > 0, got {other}"
                    ))
                }
                None => return Err("`dynamics.period`: missing".into()),
            };
            let motion = part
                .build
                .build(period, &Params::new("dynamics", &params))
                .map_err(|e| e.to_string())?;
            Ok(DynamicsConfig {
                spec,
                period,
                motion,
            })
        }
    }
}

macro_rules! as_its_table {
    ($ty:ident, $resolve:ident) => {
        impl Serialize for $ty {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                self.spec.serialize(s)
            }
        }

        impl<'de> Deserialize<'de> for $ty {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let spec = toml::Table::deserialize(d)?;
                $resolve(spec, Vocabulary::current()).map_err(serde::de::Error::custom)
            }
        }

        impl PartialEq for $ty {
            /// As the file gives it.
            fn eq(&self, other: &Self) -> bool {
                self.spec == other.spec
            }
        }

        impl std::fmt::Debug for $ty {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                self.spec.fmt(f)
            }
        }
    };
}

as_its_table!(ObservationConfig, resolve_observation);
as_its_table!(DynamicsConfig, resolve_dynamics);
