//! One picture for the whole set: a panel per capture, held-out PSNR against bake seconds
//! (log axis), a curve per configuration (its largest-budget bake's records) and a dot per
//! budget (each budget's own bake).

use anyhow::{bail, Context, Result};
use plotters::prelude::*;

use super::{Suite, Table};

/// The bundled font the plot's text is drawn with (DejaVu Sans; licence beside it), so
/// plotting needs no system fonts.
static FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

/// Colours by configuration, in order of first appearance.
pub const COLOURS: [RGBColor; 9] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(23, 190, 207),
];

/// Panel size in pixels.
const PANEL: (u32, u32) = (640, 420);

/// The suite's plot as PNG bytes.
pub fn plot(s: &Suite) -> Result<Vec<u8>> {
    draw_panels(s, panel)
}

/// The bytes plot as PNG bytes: a panel per capture, held-out PSNR against asset bytes (log
/// axis), a dot per storage of each bake (labelled with the storage) coloured by
/// configuration.
pub fn plot_bytes(s: &Suite) -> Result<Vec<u8>> {
    draw_panels(s, bytes_panel)
}

type PanelFn = fn(&Table, &Area, &[String]) -> Result<(), Box<dyn std::error::Error>>;

/// One panel per capture (three to a row), drawn by `draw`, encoded as PNG.
fn draw_panels(s: &Suite, draw: PanelFn) -> Result<Vec<u8>> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let font_ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok()
    });
    if !font_ok {
        bail!("the bundled DejaVu Sans font could not be loaded");
    }
    let n = s.tables.len().max(1);
    let cols = n.min(3);
    let rows = n.div_ceil(cols);
    let (w, h) = (PANEL.0 * cols as u32, PANEL.1 * rows as u32);
    let mut configs: Vec<String> = Vec::new();
    for t in &s.tables {
        for c in &t.cells {
            if !configs.contains(&c.config) {
                configs.push(c.config.clone());
            }
        }
    }
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("plot: {e}");
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let panels = root.split_evenly((rows, cols));
        for (t, area) in s.tables.iter().zip(panels.iter()) {
            draw(t, area, &configs).map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    let mut png = Vec::new();
    {
        use image::ImageEncoder;
        // Plots are committed with the figures: the smaller file is worth the time.
        image::codecs::png::PngEncoder::new_with_quality(
            &mut png,
            image::codecs::png::CompressionType::Best,
            image::codecs::png::FilterType::Adaptive,
        )
        .write_image(&buf, w, h, image::ExtendedColorType::Rgb8)
        .context("encoding the plot")?;
    }
    Ok(png)
}

fn bytes_panel(
    t: &Table,
    area: &Area,
    configs: &[String],
) -> Result<(), Box<dyn std::error::Error>> {
    let points: Vec<(&str, &str, f64, f64)> = t
        .cells
        .iter()
        .flat_map(|c| {
            c.storages
                .iter()
                .map(move |v| (c.config.as_str(), v.name.as_str(), v.bytes as f64, v.psnr))
        })
        .filter(|(_, _, b, p)| *b > 0.0 && p.is_finite())
        .collect();
    let (b_lo, b_hi, p_lo, p_hi) = points.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), &(_, _, x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
    );
    let (x_lo, x_hi, y_lo, y_hi) = if b_lo.is_finite() {
        (
            b_lo / 1.5,
            b_hi * 1.5,
            (p_lo - 1.0).floor(),
            (p_hi + 1.0).ceil(),
        )
    } else {
        (1e3, 1e7, 0.0, 40.0)
    };
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{} (bytes)", t.name), ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d((x_lo..x_hi).log_scale(), y_lo..y_hi)?;
    chart
        .configure_mesh()
        .x_desc("asset MB (log)")
        .x_label_formatter(&|b| format!("{:.2}", b / 1e6))
        .y_desc("held-out PSNR (dB)")
        .label_style(("sans-serif", 12))
        .draw()?;
    for (i, name) in configs.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let mine: Vec<_> = points.iter().filter(|p| p.0 == name).collect();
        if mine.is_empty() {
            continue;
        }
        chart
            .draw_series(
                mine.iter()
                    .map(|&&(_, _, b, p)| Circle::new((b, p), 5, colour.filled())),
            )?
            .label(name.clone())
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
        // Labels beside the dots; `chosen` only when it is not one of the uniform storages.
        let labelled = mine.iter().filter(|&&&(_, s, b, p)| {
            s != "chosen"
                || !mine
                    .iter()
                    .any(|&&(_, o, ob, op)| o != "chosen" && ob == b && op == p)
        });
        chart.draw_series(labelled.map(|&&(_, s, b, p)| {
            EmptyElement::at((b, p))
                + Text::new(s.to_string(), (7, -14), ("sans-serif", 11).into_font())
        }))?;
    }
    legend(&mut chart)
}

/// The legend both plots draw: lower right, over a light box.
fn legend<'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, CT>,
) -> Result<(), Box<dyn std::error::Error>> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .label_font(("sans-serif", 12))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// A log axis's tick label, only at 1, 2 and 5 times a power of ten: every tick labelled
/// runs the decade's labels into each other.
fn one_two_five(v: f64) -> String {
    if !(v.is_finite() && v > 0.0) {
        return String::new();
    }
    let m = v / 10f64.powf(v.log10().floor());
    if [1.0, 2.0, 5.0, 10.0]
        .iter()
        .any(|k| (m - k).abs() < 1e-3 * k)
    {
        format!("{v:.0}")
    } else {
        String::new()
    }
}

fn panel(t: &Table, area: &Area, configs: &[String]) -> Result<(), Box<dyn std::error::Error>> {
    let x_hi = t.budgets.iter().copied().fold(1.0, f64::max) * 1.15;
    let x_lo = (t.budgets.iter().copied().fold(x_hi, f64::min) / 8.0).max(0.5);
    // The interesting range: from a little below the worst budget dot to above the best.
    let dots = t.cells.iter().map(|c| c.psnr).filter(|p| p.is_finite());
    let (lo, hi) = dots.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p), b.max(p))
    });
    let (y_lo, y_hi) = if lo.is_finite() {
        ((lo - 4.0).floor(), (hi + 1.0).ceil())
    } else {
        (0.0, 40.0)
    };
    let title = match &t.mesh {
        Some(_) => format!("{} (coarse proxy)", t.name),
        None => t.name.clone(),
    };
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d((x_lo..x_hi).log_scale(), y_lo..y_hi)?;
    chart
        .configure_mesh()
        .x_desc("bake seconds (log)")
        .x_label_formatter(&|s| one_two_five(*s))
        .y_desc("held-out PSNR (dB)")
        .label_style(("sans-serif", 12))
        .draw()?;
    for (i, name) in configs.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let curve = t.curves.iter().find(|(c, _)| c == name);
        if let Some((_, recs)) = curve {
            let curve: Vec<(f64, f64)> = recs
                .iter()
                .filter(|r| r.seconds >= x_lo && r.test_psnr.is_finite())
                .map(|r| (r.seconds, r.test_psnr.clamp(y_lo, y_hi)))
                .collect();
            chart
                .draw_series(LineSeries::new(curve, colour.stroke_width(2)))?
                .label(name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
        }
        let dots = t
            .cells
            .iter()
            .filter(|c| &c.config == name && c.psnr.is_finite())
            .map(|c| {
                Circle::new(
                    (c.seconds.clamp(x_lo, x_hi), c.psnr.clamp(y_lo, y_hi)),
                    5,
                    colour.filled(),
                )
            });
        let drawn = chart.draw_series(dots)?;
        // A configuration with results but no records is named by its dot.
        if curve.is_none() {
            drawn
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
        }
    }
    legend(&mut chart)
}

#[cfg(test)]
mod tests {
    use super::super::testing::table;
    use super::super::Suite;
    use super::*;

    #[test]
    fn log_axis_labels_only_one_two_five() {
        let labels: Vec<String> = [10.0, 20.0, 30.0, 50.0, 60.0, 100.0, 200.0, 300.0, 500.0]
            .iter()
            .map(|&v| one_two_five(v))
            .collect();
        assert_eq!(labels, ["10", "20", "", "50", "", "100", "200", "", "500"]);
        assert_eq!(one_two_five(0.0), "");
    }

    #[test]
    fn one_panel_per_capture_with_every_configuration() {
        let s = Suite {
            tables: vec![table("a"), table("b"), table("c"), table("d")],
            summary: Vec::new(),
        };
        let png = plot(&s).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (3 * PANEL.0, 2 * PANEL.1));
        let has = |c: RGBColor| img.pixels().any(|p| p.0 == [c.0, c.1, c.2]);
        assert!(has(COLOURS[0]) && has(COLOURS[1]));
        // The bytes plot beside it: same panels, a dot per storage.
        let png = plot_bytes(&s).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (3 * PANEL.0, 2 * PANEL.1));
        let has = |c: RGBColor| img.pixels().any(|p| p.0 == [c.0, c.1, c.2]);
        assert!(has(COLOURS[0]) && has(COLOURS[1]));
    }
}
