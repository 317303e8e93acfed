//! The slave group in its AL state ([`Running`]), its process image
//! behind [`BorrowFlag`], and the one process-data cycle of any state
//! ([`Cycle`]).

use super::link::MAX_PDI;
use super::*;
use crate::ethercat::rack::MAX_RACK;
use ethercrab::subdevice_group::HasPdi;

/// The group, its process image behind [`BorrowFlag`] (never waits), not
/// ethercrab's default spin lock (which yields when contended).
pub(super) type Group<S, D = NoDc> = SubDeviceGroup<MAX_RACK, MAX_PDI, BorrowFlag, S, D>;

/// `MainDevice::init`'s group filter: every slave into the one group.
pub(super) fn the_group<'g>(
    g: &'g Group<PreOp>,
    _: &SubDevice,
) -> Result<&'g dyn SubDeviceGroupHandle, ethercrab::error::Error> {
    Ok(g)
}

/// The group in its AL state: SAFE-OP while disabled (inputs valid, the
/// outputs and the SM watchdog not in force), OP while enabled.
pub(super) enum Running {
    SafeOp(Group<SafeOp>),
    Op(Group<Op>),
    /// With distributed clocks (SYNC0 at the loop period).
    SafeOpDc(Group<SafeOp, HasDc>),
    /// With distributed clocks.
    OpDc(Group<Op, HasDc>),
}

impl Running {
    pub(super) fn is_op(&self) -> bool {
        matches!(self, Self::Op(_) | Self::OpDc(_))
    }
}

/// Applies `$body` to the group of any variant of a `Running`.
macro_rules! on_group {
    ($r:expr, $g:ident => $body:expr) => {
        match $r {
            Running::SafeOp($g) => $body,
            Running::Op($g) => $body,
            Running::SafeOpDc($g) => $body,
            Running::OpDc($g) => $body,
        }
    };
}
pub(super) use on_group;

/// What one process-data round trip tells: the working counter, the
/// lowest AL state of the slaves (read in the same frame: one slave out of
/// OP makes it SAFE-OP or below), and the distributed clock's system time
/// (`None` without DC).
pub(super) type CycleResult = (u16, Option<SubDeviceState>, Option<u64>);

/// One process-data round trip of the group in any of its states, so the
/// tick needs one arm, not one per typestate: `tx_rx` without distributed
/// clocks, `tx_rx_dc` (an `FRMW` of the system time in the same frame)
/// with them. Real-time safe as they are (module docs of `master`).
pub(super) trait Cycle {
    /// The round trip, as ethercrab's future (driven by [`Link::block_on`](super::link::Link::block_on)).
    fn cycle<'a>(
        &'a self,
        md: &'a MainDevice<'a>,
    ) -> impl Future<Output = Result<CycleResult, ethercrab::error::Error>> + 'a;
}

impl<S: HasPdi> Cycle for Group<S, NoDc> {
    async fn cycle<'a>(
        &'a self,
        md: &'a MainDevice<'a>,
    ) -> Result<CycleResult, ethercrab::error::Error> {
        let r = self.tx_rx(md).await?;
        Ok((r.working_counter, lowest(&r.subdevice_states), None))
    }
}

impl<S: HasPdi> Cycle for Group<S, HasDc> {
    async fn cycle<'a>(
        &'a self,
        md: &'a MainDevice<'a>,
    ) -> Result<CycleResult, ethercrab::error::Error> {
        let r = self.tx_rx_dc(md).await?;
        let t = Some(r.extra.dc_system_time);
        Ok((r.working_counter, lowest(&r.subdevice_states), t))
    }
}

/// The lowest AL state of a group (INIT 1 < PRE-OP 2 < SAFE-OP 4 < OP 8).
fn lowest(states: &[SubDeviceState]) -> Option<SubDeviceState> {
    states.iter().copied().min_by_key(|s| u8::from(*s))
}
