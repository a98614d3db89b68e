//! cqnet's own parts, listed through the same methods a program uses for
//! its own ([`Parts::new`](super::Parts::new)).

use fusion_graph::Scenario;

use super::{BuildNode, Carries, ParamError, Parts, ProtocolFactory, Setup};
use crate::fusion::{average_consensus, short_memory_consensus, InformationFusion, RandomExchange};
use crate::location::{LocationConfig, ThresholdDesign};
use crate::nodes::trackers::{
    kl_fusion_rounds, Cooperation, ExchangeCooperation, KlCooperation, TrackerNode,
};
use crate::sensor_manager::{self, Closest, Manager, OfflinePcrlb, Scoring, UniformRandom};
use crate::{AnyNode, LocatorNode, NodeError, ProcessingNode, Start};

/// Adds cqnet's own parts to `parts`, in the order the scenario format's
/// vocabulary lists them, under the names and shapes it gives them (so
/// that neither is written twice).
pub(super) fn add(parts: Parts) -> Parts {
    use fusion_graph::scenario::{ConsensusProtocol as P, SensorManagerKind as M};
    let mut parts = parts
        .protocol(P::AVERAGE.name(), Average)
        .exact_sums(P::EXACT.name())
        .protocol(P::SHORT_MEMORY.name(), ShortMemory);
    let nodes: [(P, BuildNode); 5] = [
        (P::RANDOM_EXCHANGE, random_exchange),
        (P::KL_CONSENSUS, kl_consensus),
        (P::KL_DIFFUSION, kl_diffusion),
        (P::KL_ITERATIVE, kl_iterative),
        (P::ML_LOCATION, locator),
    ];
    for (p, build) in nodes {
        parts = parts.node(p.name(), (p.shape(), build));
    }
    parts
        .manager(M::RANDOM.name(), random)
        .manager(M::CLOSEST.name(), closest)
        .manager(M::PCRLB.name(), pcrlb)
        .manager(M::PCRLB_AT_ESTIMATE.name(), pcrlb_at_estimate)
        .manager(M::PCRLB_AUX.name(), pcrlb_aux)
        .manager(M::PCRLB_OFFLINE.name(), pcrlb_offline)
}

// The built-in parts take no parameters of their own, but the locator.

/// Average consensus: it carries every part of the information vector.
struct Average;

impl ProtocolFactory for Average {
    fn carries(&self) -> Carries {
        Carries {
            late: true,
            s_obs: true,
        }
    }

    fn build(&self, setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
        setup.params.only(&[])?;
        Ok(Box::new(
            average_consensus(
                setup.node,
                setup.topology,
                setup.rounds(),
                setup.round_timeout(),
                setup.scenario.consensus.auxiliary_fim,
            )
            .stop_awaiting_the_late(),
        ))
    }
}

/// Short-memory consensus: average consensus's messages, with one round
/// of memory. Its weight α is `consensus.params.alpha` if given, else the
/// fusion graph's (every node alive), which every node computes alike.
struct ShortMemory;

impl ProtocolFactory for ShortMemory {
    fn carries(&self) -> Carries {
        Carries {
            late: true,
            s_obs: true,
        }
    }

    fn build(&self, setup: &Setup<'_>) -> Result<InformationFusion, ParamError> {
        setup.params.only(&["alpha"])?;
        let alpha = match setup.params.number_if_given("alpha", 0.0..=0.99)? {
            Some(alpha) => alpha,
            None => {
                let t = setup.topology;
                t.mixing(&t.all_alive()).memory_weight()
            }
        };
        Ok(Box::new(
            short_memory_consensus(
                setup.node,
                setup.topology,
                setup.rounds(),
                setup.round_timeout(),
                alpha,
                setup.scenario.consensus.auxiliary_fim,
            )
            .stop_awaiting_the_late(),
        ))
    }
}

fn random_exchange(setup: &Setup<'_>, _: Start) -> Result<AnyNode, NodeError> {
    setup.params.only(&[])?;
    let exchange = RandomExchange::new(
        setup.node,
        setup.topology,
        setup.round_timeout(),
        setup.scenario.seed,
    );
    tracker(setup, ExchangeCooperation::default(), exchange)
}

fn kl_consensus(setup: &Setup<'_>, _: Start) -> Result<AnyNode, NodeError> {
    kl(setup, setup.scenario.consensus.rounds, false)
}

fn kl_diffusion(setup: &Setup<'_>, _: Start) -> Result<AnyNode, NodeError> {
    kl(setup, 1, true)
}

fn kl_iterative(setup: &Setup<'_>, _: Start) -> Result<AnyNode, NodeError> {
    kl(setup, setup.scenario.consensus.rounds, true)
}

fn kl(setup: &Setup<'_>, rounds: u32, neighbourhood: bool) -> Result<AnyNode, NodeError> {
    setup.params.only(&[])?;
    let fusion = kl_fusion_rounds(setup.scenario, setup.topology, setup.node, rounds);
    tracker(setup, KlCooperation::new(neighbourhood), fusion)
}

fn tracker<C: Cooperation + 'static>(
    setup: &Setup<'_>,
    cooperation: C,
    protocol: C::Protocol,
) -> Result<AnyNode, NodeError> {
    let node = TrackerNode::new(
        setup.scenario,
        setup.topology,
        setup.node,
        cooperation,
        protocol,
    )?;
    Ok(Box::new(ProcessingNode::new(node)))
}

fn locator(setup: &Setup<'_>, _: Start) -> Result<AnyNode, NodeError> {
    let config = location_config(setup.scenario)?;
    let node = LocatorNode::new(setup.scenario, setup.topology, setup.node, config)?;
    Ok(Box::new(ProcessingNode::new(node)))
}

/// `consensus.params` of `ml_location`: `grid_x`, `grid_y` (5 to 61
/// points, default 21), `refinements` (0 to 4, default 2) and `thresholds`
/// (`"designed"`, the default for amplitude sensors, or `"uniform"`).
pub fn location_config(scenario: &Scenario) -> Result<LocationConfig, ParamError> {
    let params = super::protocol_params(scenario);
    params.only(&["grid_x", "grid_y", "refinements", "thresholds"])?;
    let axis = |name| params.integer(name, 5..=61, 21).map(|v| v as usize);
    let amplitude = scenario
        .observation
        .law()
        .is::<bounds::observation::Amplitude>();
    let default = if amplitude { "designed" } else { "uniform" };
    let thresholds = match params.text("thresholds", default)? {
        "designed" if amplitude || scenario.quantizer.raw => ThresholdDesign::Designed,
        "designed" => {
            return Err(params.error(
                "thresholds",
                "\"uniform\": the designed thresholds are for amplitude sensors",
                "\"designed\"",
            ))
        }
        "uniform" => ThresholdDesign::Uniform,
        other => {
            return Err(params.error(
                "thresholds",
                "\"designed\" or \"uniform\"",
                format!("\"{other}\""),
            ))
        }
    };
    Ok(LocationConfig {
        grid: [axis("grid_x")?, axis("grid_y")?],
        refinements: params.integer("refinements", 0..=4, 2)? as usize,
        thresholds,
    })
}

fn random(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(Manager::Alone(Box::new(UniformRandom::for_scenario(
        setup.scenario,
    ))))
}

fn closest(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(Manager::Alone(Box::new(Closest::for_scenario(
        setup.scenario,
    ))))
}

fn pcrlb(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(sensor_manager::negotiated(
        setup.scenario,
        setup.topology,
        setup.node,
        Scoring::Conditional,
    ))
}

fn pcrlb_at_estimate(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    Ok(sensor_manager::negotiated(
        setup.scenario,
        setup.topology,
        setup.node,
        Scoring::AtEstimate,
    ))
}

fn pcrlb_aux(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    if !setup.scenario.consensus.auxiliary_fim {
        return Err(ParamError {
            key: "consensus.auxiliary_fim".into(),
            expected: "true: sensors.manager = \"pcrlb_aux\" scores by the auxiliary FIM".into(),
            got: "false".into(),
        });
    }
    Ok(sensor_manager::negotiated(
        setup.scenario,
        setup.topology,
        setup.node,
        Scoring::Auxiliary,
    ))
}

fn pcrlb_offline(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    setup.params.only(&[])?;
    let manager =
        OfflinePcrlb::for_scenario(setup.scenario, setup.topology).map_err(|e| ParamError {
            key: "sensors.manager".into(),
            expected: "a scenario whose offline PCRLB can be computed".into(),
            got: e.to_string(),
        })?;
    Ok(Manager::Alone(Box::new(manager)))
}
