//! `kind = "none"`: no safety filter, the nominal input is issued as it is.

use serde::{Deserialize, Serialize};

use crate::barrier::BarrierForm;
use crate::filter::Params;
use crate::filter::{ChannelInput, ChannelOutcome, FilterContext, FilterError, ParamError, SafetyFilter};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoFilterParams {}

impl Params for NoFilterParams {}

/// Issues the nominal input.
pub struct NoFilter;

/// The filter of a `kind = "none"` table.
pub fn build(_: &NoFilterParams, _: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    Ok(Box::new(NoFilter))
}

impl SafetyFilter for NoFilter {
    fn barrier_form(&self) -> Option<BarrierForm> {
        None
    }
    fn uses_prediction(&self) -> bool {
        false
    }
    fn filter_channel(&mut self, _: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        Ok(None)
    }
}
