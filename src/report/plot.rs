//! Error-against-time plots on log–log axes with `plotters`: SVG through its SVG backend (text stays
//! text, so no font is needed) and a raster copy through its bitmap backend with the DejaVu Sans font
//! compiled in (`dejavu` crate), so neither depends on the fonts installed on the machine.

use crate::image::{srgb_to_linear, ImageBuf};
use anyhow::anyhow;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::sync::OnceLock;

/// One line of the plot: (seconds, error) points in time order.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Size of both plots in pixels (SVG user units).
pub const PLOT_SIZE: (u32, u32) = (900, 600);

/// The error plot as an SVG document.
pub fn error_plot_svg(series: &[Series], metric_label: &str, title: &str) -> anyhow::Result<String> {
    // Text stays text in SVG, but plotters measures it with the registered font to lay out labels.
    register_embedded_font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        draw(&root, series, metric_label, title).map_err(|e| anyhow!("cannot draw the SVG plot: {e}"))?;
        root.present().map_err(|e| anyhow!("cannot draw the SVG plot: {e}"))?;
    }
    Ok(svg)
}

/// The error plot as a linear RGB image, ready for `write_image` (which encodes PNG as sRGB again).
pub fn error_plot_image(series: &[Series], metric_label: &str, title: &str) -> anyhow::Result<ImageBuf> {
    register_embedded_font()?;
    let (w, h) = PLOT_SIZE;
    let mut rgb = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, PLOT_SIZE).into_drawing_area();
        draw(&root, series, metric_label, title).map_err(|e| anyhow!("cannot draw the PNG plot: {e}"))?;
        root.present().map_err(|e| anyhow!("cannot draw the PNG plot: {e}"))?;
    }
    let mut img = ImageBuf::new(w as usize, h as usize, 3);
    // The bitmap holds display (sRGB) codes; our images are linear and writers encode them back.
    for (dst, &src) in img.data.iter_mut().zip(&rgb) {
        *dst = srgb_to_linear(src as f32 / 255.0);
    }
    Ok(img)
}

fn register_embedded_font() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(anyhow!("the embedded DejaVu Sans font could not be parsed"))
    }
}

/// Colours that stay distinguishable for up to ten lines (Tableau 10).
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Points a log axis can show: finite and positive.
fn plottable(p: &(f64, f64)) -> bool {
    p.0.is_finite() && p.1.is_finite() && p.0 > 0.0 && p.1 > 0.0
}

/// Axis range padded by a quarter decade each side, so end points do not sit on the frame.
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !(lo.is_finite() && hi > 0.0) {
        return 0.1..1.0;
    }
    let pad = 10f64.powf(0.25);
    lo / pad..hi * pad
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    series: &[Series],
    metric_label: &str,
    title: &str,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let all = || series.iter().flat_map(|s| s.points.iter().filter(|p| plottable(p)));
    let x_range = log_range(all().map(|p| p.0));
    let y_range = log_range(all().map(|p| p.1));
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 22))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(80)
        .build_cartesian_2d(x_range.log_scale(), y_range.log_scale())?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc(metric_label)
        .x_label_formatter(&|v| format!("{v:.3}"))
        .y_label_formatter(&|v| format!("{v:.1e}"))
        .label_style(("sans-serif", 14))
        .draw()?;
    for (i, s) in series.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let points: Vec<(f64, f64)> = s.points.iter().copied().filter(plottable).collect();
        chart
            .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(points.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 16))
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> Vec<Series> {
        vec![
            Series { name: "pt".into(), points: vec![(0.1, 1.0), (1.0, 0.1), (10.0, 0.01)] },
            Series { name: "bdpt".into(), points: vec![(0.1, 0.5), (1.0, f64::NAN), (10.0, 0.0)] },
        ]
    }

    #[test]
    fn svg_names_every_series_and_axis() {
        let svg = error_plot_svg(&example(), "relative MSE", "cornell").unwrap();
        for text in ["\npt\n", "\nbdpt\n", "relative MSE", "time (s)", "cornell", "<polyline"] {
            assert!(svg.contains(text), "missing {text:?}");
        }
    }

    #[test]
    fn raster_plot_draws_text_and_lines_on_white() {
        let img = error_plot_image(&example(), "relative MSE", "cornell").unwrap();
        assert_eq!((img.width, img.height), (PLOT_SIZE.0 as usize, PLOT_SIZE.1 as usize));
        let dark = img.data.chunks(3).filter(|p| p.iter().all(|&v| v < 0.1)).count();
        let white = img.data.chunks(3).filter(|p| p.iter().all(|&v| v > 0.99)).count();
        // Mostly background, but with axes, tick labels and the caption drawn in black.
        assert!(white > img.width * img.height / 2, "{white} white pixels");
        assert!(dark > 2000, "only {dark} dark pixels: no text or axes drawn");
    }
}
