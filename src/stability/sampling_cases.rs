//! PLACEHOLDER: filled by the stability helpers.

use super::Case;

pub fn cases() -> Vec<Case> {
    Vec::new()
}
