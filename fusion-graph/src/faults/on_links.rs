//! What the faults on links share: selectors that take links, a window,
//! and an effect on the rule of each link they take. A kind says what its
//! effect is; [`FaultKind`] follows for it.

use super::kind::{FaultKind, Targets, Window};
use super::select::{check_links, link_targets, links_text, takes_link, LinkSelector};
use crate::check::Check;
use crate::shaper::LinkRule;
use crate::ScenarioError;
use wire::ActorId;

/// A fault on the links its selectors take, while its window holds.
pub trait LinkFault {
    fn links(&self) -> &[LinkSelector];

    fn window(&self) -> Window;

    /// Checks the kind's own values; the selectors and the window are
    /// checked for every link fault.
    fn check_values(&self, check: &Check) -> Result<(), ScenarioError>;

    /// What it does, for the summary's line: `loss 0.3`.
    fn effect(&self) -> String;

    /// Adds its effect to the rule of a link it takes.
    fn shape(&self, rule: &mut LinkRule);

    /// See [`FaultKind::loses_messages`].
    fn loses_messages(&self) -> bool {
        false
    }
}

/// `links()` and `window()` from the kind's `links`, `at_step` and
/// `duration` fields.
macro_rules! on_its_links {
    () => {
        fn links(&self) -> &[$crate::faults::LinkSelector] {
            &self.links
        }

        fn window(&self) -> $crate::faults::Window {
            $crate::faults::Window::lasting(self.at_step, self.duration)
        }
    };
}
pub(super) use on_its_links;

impl<T: LinkFault> FaultKind for T {
    fn window(&self) -> Window {
        LinkFault::window(self)
    }

    fn targets(&self) -> Targets<'_> {
        link_targets(self.links())
    }

    fn check(&self, check: &Check) -> Result<(), ScenarioError> {
        check_links(self.links(), check)?;
        self.check_values(check)?;
        let window = LinkFault::window(self);
        check.duration(window.end.map(|end| end - window.at_step))
    }

    fn describe(&self) -> String {
        format!("{} on {}", self.effect(), links_text(self.links()))
    }

    fn loses_messages(&self) -> bool {
        LinkFault::loses_messages(self)
    }

    fn acts_on_links(&self) -> bool {
        true
    }

    fn shape_link(&self, fault: usize, from: ActorId, to: ActorId, rule: &mut LinkRule) {
        if takes_link(self.links(), fault, from, to) {
            self.shape(rule);
        }
    }
}
