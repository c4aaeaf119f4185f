//! The report page: a fixed HTML template filled with the images `compare` writes beside it (final
//! renders, false-colour error maps, zoomed crops of the worst regions) and the error plot. Also the
//! image helpers that make those pictures from the renders and the reference.

use crate::image::{srgb_to_linear, ImageBuf};
use plotters::style::colors::colormaps::ViridisRGB;

/// Decades of relative squared error the error maps span: 1e-4 (dark blue) to 1 (yellow).
pub const ERROR_MAP_DECADES: (f64, f64) = (-4.0, 0.0);

/// A per-pixel error map in false colour (viridis over log10 error, `ERROR_MAP_DECADES`), as a
/// linear RGB image so the usual writers encode it; the same scale for every integrator.
pub fn false_colour(errors: &[f64], width: usize, height: usize) -> ImageBuf {
    let mut img = ImageBuf::new(width, height, 3);
    let (lo, hi) = ERROR_MAP_DECADES;
    for (px, &e) in img.data.chunks_mut(3).zip(errors) {
        let t = if e > 0.0 { ((e.log10() - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.0 };
        let c = ViridisRGB::get_color(t);
        for (dst, code) in px.iter_mut().zip([c.0, c.1, c.2]) {
            *dst = srgb_to_linear(code as f32 / 255.0);
        }
    }
    img
}

/// A square region of the image, in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    pub x: usize,
    pub y: usize,
    pub size: usize,
}

/// The `count` blocks of a grid of `size`-pixel squares with the highest summed error over all maps
/// (each map normalised by its own mean, so a noisy integrator does not alone choose the crops),
/// worst first. Blocks of the grid never overlap.
pub fn worst_regions(
    maps: &[Vec<f64>],
    width: usize,
    height: usize,
    size: usize,
    count: usize,
) -> Vec<Region> {
    let size = size.clamp(1, width.min(height).max(1));
    let mut scored: Vec<(f64, Region)> = Vec::new();
    let means: Vec<f64> = maps
        .iter()
        .map(|m| m.iter().filter(|v| v.is_finite()).sum::<f64>() / m.len().max(1) as f64)
        .collect();
    for y in (0..=height - size).step_by(size) {
        for x in (0..=width - size).step_by(size) {
            let mut score = 0.0;
            for (map, &mean) in maps.iter().zip(&means) {
                let block: f64 = (y..y + size)
                    .flat_map(|yy| (x..x + size).map(move |xx| map[yy * width + xx]))
                    .filter(|v| v.is_finite())
                    .sum();
                if mean > 0.0 {
                    score += block / mean;
                }
            }
            scored.push((score, Region { x, y, size }));
        }
    }
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.into_iter().take(count).map(|(_, r)| r).collect()
}

/// The pixels of `region` as a new image.
pub fn crop(img: &ImageBuf, region: Region) -> ImageBuf {
    let mut out = ImageBuf::new(region.size, region.size, img.channels);
    for y in 0..region.size {
        for x in 0..region.size {
            out.pixel_mut(x, y).copy_from_slice(img.pixel(region.x + x, region.y + y));
        }
    }
    out
}

/// What the page shows for one integrator (file names relative to the page).
#[derive(Clone, Debug)]
pub struct IntegratorEntry {
    pub name: String,
    pub image: String,
    pub exr: String,
    pub error_map: String,
    /// One file per region, in the order of `Page::regions`.
    pub crops: Vec<String>,
    /// Final time, samples and metrics, already formatted.
    pub summary: String,
}

/// Everything the page template needs.
#[derive(Clone, Debug)]
pub struct Page {
    pub title: String,
    /// Scene, reference, time budget and threads, as one line.
    pub setup: String,
    pub reference_image: String,
    pub reference_crops: Vec<String>,
    pub regions: Vec<Region>,
    pub integrators: Vec<IntegratorEntry>,
    pub plot_svg: String,
    pub csv: String,
    pub metric_note: String,
}

const TEMPLATE: &str = r#"<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{{title}}</title>
<style>
body { font-family: sans-serif; margin: 2em; background: #fafafa; color: #222; }
.row { display: flex; flex-wrap: wrap; gap: 1em; }
figure { margin: 0; }
figcaption { font-size: 0.9em; max-width: 320px; }
img.render { max-width: 320px; width: 100%; }
img.zoom { width: 160px; image-rendering: pixelated; }
table { border-collapse: collapse; }
td, th { padding: 0.2em 0.8em; border-bottom: 1px solid #ddd; text-align: left; }
</style>
</head>
<body>
<h1>{{title}}</h1>
<p>{{setup}}</p>
<h2>Error against time</h2>
<p><img src="{{plot}}" alt="error against time, log-log" style="max-width: 900px; width: 100%"></p>
<p>{{metric_note}} Data: <a href="{{csv}}">{{csv}}</a>.</p>
<h2>Final images</h2>
<div class="row">
{{images}}
</div>
<h2>Error maps</h2>
<p>Per-pixel relative squared error, viridis from 1e-4 (dark) to 1 (yellow) on a log scale, the same for every integrator.</p>
<div class="row">
{{error_maps}}
</div>
<h2>Regions with the highest error</h2>
<table>
{{crops}}
</table>
</body>
</html>
"#;

/// Escapes text for HTML content and attribute values.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

fn figure(src: &str, caption: &str, class: &str) -> String {
    format!(
        "<figure><img class=\"{class}\" src=\"{}\" alt=\"{}\"><figcaption>{caption}</figcaption></figure>",
        escape(src),
        escape(src)
    )
}

/// The page as HTML text.
pub fn render_page(page: &Page) -> String {
    let mut images = vec![figure(&page.reference_image, "reference", "render")];
    let mut error_maps = Vec::new();
    for e in &page.integrators {
        let caption = format!(
            "<b>{}</b> (<a href=\"{}\">EXR</a>)<br>{}",
            escape(&e.name),
            escape(&e.exr),
            escape(&e.summary)
        );
        images.push(figure(&e.image, &caption, "render"));
        error_maps.push(figure(&e.error_map, &format!("<b>{}</b>", escape(&e.name)), "render"));
    }
    let mut crops = String::from("<tr><th>region</th><th>reference</th>");
    for e in &page.integrators {
        crops.push_str(&format!("<th>{}</th>", escape(&e.name)));
    }
    crops.push_str("</tr>\n");
    for (i, r) in page.regions.iter().enumerate() {
        crops.push_str(&format!("<tr><td>x {}, y {}, {} px</td>", r.x, r.y, r.size));
        let cell = |src: Option<&String>| match src {
            Some(s) => format!("<td><img class=\"zoom\" src=\"{}\" alt=\"{}\"></td>", escape(s), escape(s)),
            None => "<td></td>".to_string(),
        };
        crops.push_str(&cell(page.reference_crops.get(i)));
        for e in &page.integrators {
            crops.push_str(&cell(e.crops.get(i)));
        }
        crops.push_str("</tr>\n");
    }
    TEMPLATE
        .replace("{{title}}", &escape(&page.title))
        .replace("{{setup}}", &escape(&page.setup))
        .replace("{{plot}}", &escape(&page.plot_svg))
        .replace("{{csv}}", &escape(&page.csv))
        .replace("{{metric_note}}", &escape(&page.metric_note))
        .replace("{{images}}", &images.join("\n"))
        .replace("{{error_maps}}", &error_maps.join("\n"))
        .replace("{{crops}}", &crops)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worst_region_is_the_block_holding_the_error() {
        let (w, h) = (16, 16);
        let mut map = vec![0.01; w * h];
        map[12 * w + 5] = 100.0;
        let regions = worst_regions(&[map], w, h, 8, 2);
        assert_eq!(regions[0], Region { x: 0, y: 8, size: 8 });
        assert_eq!(regions.len(), 2);
        assert_ne!(regions[1], regions[0]);
    }

    #[test]
    fn false_colour_spans_dark_to_bright() {
        let img = false_colour(&[0.0, 1e-4, 1.0, 10.0], 4, 1);
        let lum = |i: usize| img.pixel(i, 0).iter().sum::<f32>();
        assert_eq!(img.pixel(0, 0), img.pixel(1, 0), "below the scale clamps to its bottom");
        assert!(lum(2) > 5.0 * lum(0), "{} vs {}", lum(2), lum(0));
        assert_eq!(img.pixel(2, 0), img.pixel(3, 0), "above the scale clamps to its top");
    }

    #[test]
    fn page_escapes_names_and_lists_every_image() {
        let page = Page {
            title: "a <b> & c".into(),
            setup: "setup".into(),
            reference_image: "reference.png".into(),
            reference_crops: vec!["reference-crop0.png".into()],
            regions: vec![Region { x: 0, y: 0, size: 8 }],
            integrators: vec![IntegratorEntry {
                name: "hslt+mlt".into(),
                image: "hslt_mlt.png".into(),
                exr: "hslt_mlt.exr".into(),
                error_map: "hslt_mlt-error.png".into(),
                crops: vec!["hslt_mlt-crop0.png".into()],
                summary: "1 s".into(),
            }],
            plot_svg: "error.svg".into(),
            csv: "error.csv".into(),
            metric_note: "note".into(),
        };
        let html = render_page(&page);
        assert!(html.contains("a &lt;b&gt; &amp; c"));
        for f in [
            "reference.png",
            "reference-crop0.png",
            "hslt_mlt.png",
            "hslt_mlt-error.png",
            "hslt_mlt-crop0.png",
            "error.svg",
        ] {
            assert!(html.contains(&format!("src=\"{f}\"")), "{f} not shown");
        }
        assert!(!html.contains("{{"), "unfilled placeholder");
    }
}
