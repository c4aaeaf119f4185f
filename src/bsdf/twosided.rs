//! `twosided`: makes one-sided reflection models two-sided, as Mitsuba 3's `twosided` adapter.
//!
//! | Parameter       | Type   | Default    | Meaning                                                    |
//! |-----------------|--------|------------|------------------------------------------------------------|
//! | nested `<bsdf>` | bsdf   | (required) | front-side BSDF; with a single child, also the back side   |
//! | second `<bsdf>` | bsdf   | first one  | back-side BSDF                                             |
//!
//! A query from the back (cos θi < 0) is mirrored through the tangent plane (z → −z for both
//! directions) before reaching the nested model, and the sampled direction is mirrored back, exactly as
//! Mitsuba 3 does. Nested BSDFs must not transmit light.

use super::{Bsdf, BsdfContext, BsdfLoader, BsdfLobe, BsdfSample};
use crate::props::{Props, SceneError};
use crate::spectrum::Spectrum;
use glam::{Vec2, Vec3};
use std::sync::Arc;

#[derive(Debug)]
pub struct TwoSided {
    pub front: Arc<dyn Bsdf>,
    pub back: Arc<dyn Bsdf>,
}

fn flip(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.y, -v.z)
}

impl TwoSided {
    pub fn new(front: Arc<dyn Bsdf>, back: Arc<dyn Bsdf>) -> Result<TwoSided, String> {
        if front.lobes().contains(BsdfLobe::TRANSMISSION) || back.lobes().contains(BsdfLobe::TRANSMISSION) {
            return Err("only BSDFs without transmission can be nested in twosided".into());
        }
        Ok(TwoSided { front, back })
    }

    pub fn from_props(props: &Props, loader: &BsdfLoader) -> Result<TwoSided, SceneError> {
        props.expect_only(&[], &["bsdf"])?;
        let children: Vec<_> = props.objects_with_tag("bsdf").collect();
        let (front, back) = match children.as_slice() {
            [one] => {
                let b = super::from_props(one, loader)?;
                (b.clone(), b)
            }
            [a, b] => (super::from_props(a, loader)?, super::from_props(b, loader)?),
            [] => return Err(props.error("twosided needs a nested <bsdf>")),
            _ => return Err(props.error("twosided accepts at most two nested <bsdf> elements")),
        };
        TwoSided::new(front, back).map_err(|e| props.error(e))
    }

    /// The nested model facing `wi`, and whether the query has to be mirrored.
    fn side(&self, wi: Vec3) -> Option<(&dyn Bsdf, bool)> {
        if wi.z > 0.0 {
            Some((&*self.front, false))
        } else if wi.z < 0.0 {
            Some((&*self.back, true))
        } else {
            None
        }
    }
}

impl Bsdf for TwoSided {
    fn lobes(&self) -> BsdfLobe {
        self.front.lobes() | self.back.lobes()
    }

    fn eval(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> Spectrum {
        match self.side(wi) {
            Some((b, false)) => b.eval(ctx, wi, wo),
            Some((b, true)) => b.eval(ctx, flip(wi), flip(wo)),
            None => Spectrum::ZERO,
        }
    }

    fn pdf(&self, ctx: &BsdfContext, wi: Vec3, wo: Vec3) -> f32 {
        match self.side(wi) {
            Some((b, false)) => b.pdf(ctx, wi, wo),
            Some((b, true)) => b.pdf(ctx, flip(wi), flip(wo)),
            None => 0.0,
        }
    }

    fn sample(&self, ctx: &BsdfContext, wi: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        match self.side(wi)? {
            (b, false) => b.sample(ctx, wi, u_lobe, u),
            (b, true) => b.sample(ctx, flip(wi), u_lobe, u).map(|mut s| {
                s.wo = flip(s.wo);
                s
            }),
        }
    }

    fn roughness(&self) -> f32 {
        self.front.roughness().min(self.back.roughness())
    }
}
