//! The information vector a node brings to fusion, in the form consensus
//! mixes and the wire carries: symmetric matrices as their 10
//! upper-triangular entries, so that every node's arithmetic is on exactly
//! the numbers its neighbours receive.

use bounds::{Mat4, State};
use wire::{ConsensusValues, Packed, Payload};

use crate::estimator::{Contribution, NetworkSums};

/// `(δη, δΛ, ΔL, ΔL_late)` and, with the auxiliary-FIM baseline, `S_obs`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InformationVector {
    pub delta_eta: [f64; 4],
    pub delta_lambda: Packed,
    pub delta_l: Packed,
    /// The information of observations of the step before that arrived
    /// late (about x(k−1)); zero on most steps, and then not sent.
    pub delta_l_late: Packed,
    /// Present only when the auxiliary-FIM baseline runs: it doubles the
    /// bound traffic.
    pub s_obs: Option<Packed>,
}

pub use wire::{pack_mat4 as pack_matrix, unpack_mat4 as unpack_matrix};

fn scale<const N: usize>(v: &[f64; N], w: f64) -> [f64; N] {
    v.map(|x| x * w)
}

fn add_scaled<const N: usize>(acc: &mut [f64; N], w: f64, v: &[f64; N]) {
    for (a, b) in acc.iter_mut().zip(v) {
        *a += w * b;
    }
}

/// `‖a − b‖ / max(‖a‖, ‖b‖)`, 0 where both are zero.
pub fn relative_distance(a: &[f64], b: &[f64]) -> f64 {
    let norm = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>().sqrt();
    let size = norm(&mut a.iter().copied()).max(norm(&mut b.iter().copied()));
    if size == 0.0 {
        return 0.0;
    }
    norm(&mut a.iter().zip(b).map(|(x, y)| x - y)) / size
}

impl InformationVector {
    /// The estimate's parts and the bound's ΔL, with no late information
    /// and no `S_obs`: what a protocol that carries only those rebuilds
    /// from its messages.
    pub fn new(delta_eta: [f64; 4], delta_lambda: Packed, delta_l: Packed) -> Self {
        Self {
            delta_eta,
            delta_lambda,
            delta_l,
            delta_l_late: [0.0; 10],
            s_obs: None,
        }
    }

    /// A node's contribution; `S_obs` travels only `with_aux`.
    pub fn from_contribution(c: &Contribution, with_aux: bool) -> Self {
        Self {
            delta_eta: c.delta_eta.into(),
            delta_lambda: pack_matrix(&c.delta_lambda),
            delta_l: pack_matrix(&c.delta_l),
            delta_l_late: pack_matrix(&c.delta_l_late),
            s_obs: with_aux.then(|| pack_matrix(&c.s_obs)),
        }
    }

    /// The vector as network sums (after scaling an average by N_f).
    pub fn to_sums(&self) -> NetworkSums {
        Contribution {
            delta_eta: State::from(self.delta_eta),
            delta_lambda: unpack_matrix(&self.delta_lambda),
            delta_l: unpack_matrix(&self.delta_l),
            delta_l_late: unpack_matrix(&self.delta_l_late),
            s_obs: self.s_obs.as_ref().map_or(Mat4::zeros(), unpack_matrix),
        }
    }

    /// `w · self`.
    pub fn scaled(&self, w: f64) -> Self {
        Self {
            delta_eta: scale(&self.delta_eta, w),
            delta_lambda: scale(&self.delta_lambda, w),
            delta_l: scale(&self.delta_l, w),
            delta_l_late: scale(&self.delta_l_late, w),
            s_obs: self.s_obs.map(|s| scale(&s, w)),
        }
    }

    /// `self += w · other`; a part `other` lacks is left as it is.
    pub fn add_scaled(&mut self, w: f64, other: &Self) {
        add_scaled(&mut self.delta_eta, w, &other.delta_eta);
        add_scaled(&mut self.delta_lambda, w, &other.delta_lambda);
        add_scaled(&mut self.delta_l, w, &other.delta_l);
        add_scaled(&mut self.delta_l_late, w, &other.delta_l_late);
        if let (Some(a), Some(b)) = (self.s_obs.as_mut(), other.s_obs.as_ref()) {
            add_scaled(a, w, b);
        }
    }

    /// How far `other` is from `self`: the larger, over δΛ and ΔL, of the
    /// parts' distance as a share of the larger part's size
    /// (`‖a − b‖ / max(‖a‖, ‖b‖)`, 0 where both are zero). Unitless, so
    /// that the estimate's information and the bound's weigh alike; at
    /// most 2. δη is left out: an innovation, it can sum to nearly zero
    /// over the network, and has no size to be a share of.
    pub fn disagreement(&self, other: &Self) -> f64 {
        relative_distance(&self.delta_lambda, &other.delta_lambda)
            .max(relative_distance(&self.delta_l, &other.delta_l))
    }

    /// The payloads one round of it travels in: the consensus message
    /// (with ΔL_late only when it is not zero), and the auxiliary one when
    /// `S_obs` is present.
    pub fn payloads(&self, out: &mut Vec<Payload>) {
        let late = self.delta_l_late.iter().any(|v| *v != 0.0);
        out.push(Payload::Consensus(ConsensusValues {
            delta_eta: self.delta_eta,
            delta_lambda: self.delta_lambda,
            delta_l: self.delta_l,
            delta_l_late: late.then_some(self.delta_l_late),
        }));
        if let Some(s_obs) = self.s_obs {
            out.push(Payload::ConsensusAux { s_obs });
        }
    }
}

/// A neighbour's information vector as its payloads arrive.
#[derive(Debug, Clone, Default)]
pub struct InformationPieces {
    main: Option<ConsensusValues>,
    aux: Option<Packed>,
}

impl InformationPieces {
    /// Takes a payload of the information vector; false for any other.
    pub fn absorb(&mut self, payload: &Payload) -> bool {
        match payload {
            Payload::Consensus(v) => self.main = Some(v.clone()),
            Payload::ConsensusAux { s_obs } => self.aux = Some(*s_obs),
            _ => return false,
        }
        true
    }

    /// The whole vector once its parts are in (`S_obs` too when `with_aux`).
    pub fn assemble(&self, with_aux: bool) -> Option<InformationVector> {
        let main = self.main.as_ref()?;
        if with_aux && self.aux.is_none() {
            return None;
        }
        Some(InformationVector {
            delta_eta: main.delta_eta,
            delta_lambda: main.delta_lambda,
            delta_l: main.delta_l,
            delta_l_late: main.delta_l_late.unwrap_or([0.0; 10]),
            s_obs: if with_aux { self.aux } else { None },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contribution(k: f64) -> Contribution {
        let m = Mat4::from_fn(|r, c| k + (r * 4 + c) as f64);
        Contribution {
            delta_eta: State::new(k, 2.0 * k, 0.0, -k),
            delta_lambda: m + m.transpose(),
            delta_l: m * m.transpose(),
            delta_l_late: Mat4::identity() * (k - 1.5),
            s_obs: Mat4::identity() * k,
        }
    }

    #[test]
    fn the_vector_round_trips_through_its_payloads() {
        // contribution(1.5) has no late information, contribution(2.5) has.
        for (with_aux, k) in [(false, 1.5), (true, 1.5), (false, 2.5), (true, 2.5)] {
            let v = InformationVector::from_contribution(&contribution(k), with_aux);
            let mut payloads = Vec::new();
            v.payloads(&mut payloads);
            assert_eq!(payloads.len(), 1 + with_aux as usize);
            let kind = if k == 1.5 {
                wire::MessageKind::Consensus
            } else {
                wire::MessageKind::ConsensusLate
            };
            assert_eq!(payloads[0].kind(), kind);
            let mut pieces = InformationPieces::default();
            assert!(pieces.assemble(with_aux).is_none());
            for p in &payloads {
                assert!(pieces.absorb(p));
            }
            assert_eq!(pieces.assemble(with_aux), Some(v));
            assert!(!pieces.absorb(&Payload::Observation { cell: 1 }));
        }
    }

    #[test]
    fn arithmetic_is_part_by_part() {
        let a = InformationVector::from_contribution(&contribution(1.0), true);
        let b = InformationVector::from_contribution(&contribution(3.0), true);
        let mut mix = a.scaled(0.25);
        mix.add_scaled(0.75, &b);
        let sums = mix.to_sums();
        let (ca, cb) = (contribution(1.0), contribution(3.0));
        let expected_l = ca.delta_l * 0.25 + cb.delta_l * 0.75;
        assert!((sums.delta_l - expected_l).abs().max() < 1e-12);
        let expected_late = ca.delta_l_late * 0.25 + cb.delta_l_late * 0.75;
        assert!((sums.delta_l_late - expected_late).abs().max() < 1e-12);
        assert!((sums.s_obs - Mat4::identity() * 2.5).abs().max() < 1e-12);
        assert_eq!(sums.delta_eta, State::new(2.5, 5.0, 0.0, -2.5));
    }
}
