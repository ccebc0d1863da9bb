//! The report's bar charts as PNG: grouped bars, y ticks, value labels, a legend.
//!
//! Drawn on an RGB canvas with a built-in 5x7 bitmap font (upper case, digits, a
//! little punctuation; lower case is drawn as upper case), encoded with `png`.

use super::report::Report;
use super::TrialError;
use std::path::Path;

/// An RGB colour.
pub type Rgb = [u8; 3];

const WHITE: Rgb = [255, 255, 255];
const BLACK: Rgb = [0, 0, 0];
const GRID: Rgb = [220, 220, 220];
/// Colours of success, partial and failure bars.
pub const GRADE_COLOURS: [Rgb; 3] = [[46, 139, 87], [230, 159, 0], [200, 40, 40]];
/// Colours of successive methods in the cause chart.
pub const METHOD_COLOURS: [Rgb; 6] = [
    [0, 114, 178],
    [213, 94, 0],
    [0, 158, 115],
    [204, 121, 167],
    [86, 180, 233],
    [120, 120, 120],
];

/// 5x7 glyphs, one byte per row, bit 4 = leftmost column.
const FONT: &[(char, [u8; 7])] = &[
    (
        '0',
        [
            0b01110, 0b10001, 0b10011, 0b10101, 0b11001, 0b10001, 0b01110,
        ],
    ),
    (
        '1',
        [
            0b00100, 0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110,
        ],
    ),
    (
        '2',
        [
            0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b01000, 0b11111,
        ],
    ),
    (
        '3',
        [
            0b11111, 0b00010, 0b00100, 0b00010, 0b00001, 0b10001, 0b01110,
        ],
    ),
    (
        '4',
        [
            0b00010, 0b00110, 0b01010, 0b10010, 0b11111, 0b00010, 0b00010,
        ],
    ),
    (
        '5',
        [
            0b11111, 0b10000, 0b11110, 0b00001, 0b00001, 0b10001, 0b01110,
        ],
    ),
    (
        '6',
        [
            0b00110, 0b01000, 0b10000, 0b11110, 0b10001, 0b10001, 0b01110,
        ],
    ),
    (
        '7',
        [
            0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b01000, 0b01000,
        ],
    ),
    (
        '8',
        [
            0b01110, 0b10001, 0b10001, 0b01110, 0b10001, 0b10001, 0b01110,
        ],
    ),
    (
        '9',
        [
            0b01110, 0b10001, 0b10001, 0b01111, 0b00001, 0b00010, 0b01100,
        ],
    ),
    (
        'A',
        [
            0b01110, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001,
        ],
    ),
    (
        'B',
        [
            0b11110, 0b10001, 0b10001, 0b11110, 0b10001, 0b10001, 0b11110,
        ],
    ),
    (
        'C',
        [
            0b01110, 0b10001, 0b10000, 0b10000, 0b10000, 0b10001, 0b01110,
        ],
    ),
    (
        'D',
        [
            0b11100, 0b10010, 0b10001, 0b10001, 0b10001, 0b10010, 0b11100,
        ],
    ),
    (
        'E',
        [
            0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b11111,
        ],
    ),
    (
        'F',
        [
            0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b10000,
        ],
    ),
    (
        'G',
        [
            0b01110, 0b10001, 0b10000, 0b10111, 0b10001, 0b10001, 0b01111,
        ],
    ),
    (
        'H',
        [
            0b10001, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001,
        ],
    ),
    (
        'I',
        [
            0b01110, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110,
        ],
    ),
    (
        'J',
        [
            0b00111, 0b00010, 0b00010, 0b00010, 0b00010, 0b10010, 0b01100,
        ],
    ),
    (
        'K',
        [
            0b10001, 0b10010, 0b10100, 0b11000, 0b10100, 0b10010, 0b10001,
        ],
    ),
    (
        'L',
        [
            0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b11111,
        ],
    ),
    (
        'M',
        [
            0b10001, 0b11011, 0b10101, 0b10101, 0b10001, 0b10001, 0b10001,
        ],
    ),
    (
        'N',
        [
            0b10001, 0b10001, 0b11001, 0b10101, 0b10011, 0b10001, 0b10001,
        ],
    ),
    (
        'O',
        [
            0b01110, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110,
        ],
    ),
    (
        'P',
        [
            0b11110, 0b10001, 0b10001, 0b11110, 0b10000, 0b10000, 0b10000,
        ],
    ),
    (
        'Q',
        [
            0b01110, 0b10001, 0b10001, 0b10001, 0b10101, 0b10010, 0b01101,
        ],
    ),
    (
        'R',
        [
            0b11110, 0b10001, 0b10001, 0b11110, 0b10100, 0b10010, 0b10001,
        ],
    ),
    (
        'S',
        [
            0b01111, 0b10000, 0b10000, 0b01110, 0b00001, 0b00001, 0b11110,
        ],
    ),
    (
        'T',
        [
            0b11111, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100,
        ],
    ),
    (
        'U',
        [
            0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110,
        ],
    ),
    (
        'V',
        [
            0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01010, 0b00100,
        ],
    ),
    (
        'W',
        [
            0b10001, 0b10001, 0b10001, 0b10101, 0b10101, 0b10101, 0b01010,
        ],
    ),
    (
        'X',
        [
            0b10001, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001, 0b10001,
        ],
    ),
    (
        'Y',
        [
            0b10001, 0b10001, 0b10001, 0b01010, 0b00100, 0b00100, 0b00100,
        ],
    ),
    (
        'Z',
        [
            0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b11111,
        ],
    ),
    (' ', [0; 7]),
    (
        '%',
        [
            0b11000, 0b11001, 0b00010, 0b00100, 0b01000, 0b10011, 0b00011,
        ],
    ),
    (
        '-',
        [
            0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000,
        ],
    ),
    (
        '.',
        [
            0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b01100,
        ],
    ),
    (
        ',',
        [
            0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b00100, 0b01000,
        ],
    ),
    (
        ':',
        [
            0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b01100, 0b00000,
        ],
    ),
    (
        '/',
        [
            0b00000, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b00000,
        ],
    ),
    (
        '(',
        [
            0b00010, 0b00100, 0b01000, 0b01000, 0b01000, 0b00100, 0b00010,
        ],
    ),
    (
        ')',
        [
            0b01000, 0b00100, 0b00010, 0b00010, 0b00010, 0b00100, 0b01000,
        ],
    ),
    (
        '_',
        [
            0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b11111,
        ],
    ),
    (
        '+',
        [
            0b00000, 0b00100, 0b00100, 0b11111, 0b00100, 0b00100, 0b00000,
        ],
    ),
    (
        '=',
        [
            0b00000, 0b00000, 0b11111, 0b00000, 0b11111, 0b00000, 0b00000,
        ],
    ),
    (
        '?',
        [
            0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b00000, 0b00100,
        ],
    ),
];

fn glyph(c: char) -> [u8; 7] {
    let c = c.to_ascii_uppercase();
    FONT.iter()
        .find(|(g, _)| *g == c)
        .or_else(|| FONT.iter().find(|(g, _)| *g == '?'))
        .map_or([0; 7], |(_, rows)| *rows)
}

/// An RGB image being drawn.
#[derive(Debug, Clone)]
pub struct Canvas {
    /// Width (pixels).
    pub width: usize,
    /// Height (pixels).
    pub height: usize,
    /// Row-major RGB bytes.
    pub rgb: Vec<u8>,
}

impl Canvas {
    /// A white canvas.
    pub fn new(width: usize, height: usize) -> Self {
        Canvas {
            width,
            height,
            rgb: WHITE.repeat(width * height),
        }
    }

    /// The colour at (x, y), y down.
    pub fn pixel(&self, x: usize, y: usize) -> Rgb {
        let i = 3 * (y * self.width + x);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Fills the rectangle [x, x+w) x [y, y+h), clipped to the canvas.
    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, colour: Rgb) {
        let x0 = x.clamp(0, self.width as i64) as usize;
        let x1 = (x + w).clamp(0, self.width as i64) as usize;
        let y0 = y.clamp(0, self.height as i64) as usize;
        let y1 = (y + h).clamp(0, self.height as i64) as usize;
        for row in y0..y1 {
            for col in x0..x1 {
                let i = 3 * (row * self.width + col);
                self.rgb[i..i + 3].copy_from_slice(&colour);
            }
        }
    }

    /// Width in pixels of `text` at `scale`.
    pub fn text_width(text: &str, scale: i64) -> i64 {
        let n = text.chars().count() as i64;
        if n == 0 {
            0
        } else {
            (6 * n - 1) * scale
        }
    }

    /// Draws `text` with its top-left corner at (x, y), each font pixel `scale` wide.
    pub fn text(&mut self, x: i64, y: i64, text: &str, scale: i64, colour: Rgb) {
        for (i, c) in text.chars().enumerate() {
            let gx = x + 6 * scale * i as i64;
            for (row, bits) in glyph(c).iter().enumerate() {
                for col in 0..5 {
                    if bits & (0b10000 >> col) != 0 {
                        self.fill_rect(
                            gx + col * scale,
                            y + row as i64 * scale,
                            scale,
                            scale,
                            colour,
                        );
                    }
                }
            }
        }
    }

    /// Draws `text` centred horizontally on `cx`.
    pub fn text_centred(&mut self, cx: i64, y: i64, text: &str, scale: i64, colour: Rgb) {
        self.text(
            cx - Self::text_width(text, scale) / 2,
            y,
            text,
            scale,
            colour,
        );
    }

    /// Encodes the canvas as an 8-bit RGB PNG.
    pub fn to_png(&self, path: &Path) -> Result<Vec<u8>, TrialError> {
        let mut bytes = Vec::new();
        let png_err = |e: png::EncodingError| TrialError::Png {
            path: path.to_path_buf(),
            detail: e.to_string(),
        };
        {
            let mut encoder = png::Encoder::new(&mut bytes, self.width as u32, self.height as u32);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder.write_header().map_err(png_err)?;
            writer.write_image_data(&self.rgb).map_err(png_err)?;
        }
        Ok(bytes)
    }

    /// Writes the canvas to `path` as PNG (atomically: temporary file, then rename).
    pub fn save_png(&self, path: &Path) -> Result<(), TrialError> {
        Ok(crate::fsio::write(path, &self.to_png(path)?)?)
    }
}

/// Where one bar was drawn (pixels, y down): for tests and image maps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bar {
    /// Group index.
    pub group: usize,
    /// Series index.
    pub series: usize,
    /// Left edge.
    pub x: i64,
    /// Top edge.
    pub y: i64,
    /// Width.
    pub w: i64,
    /// Height (0 for a zero value).
    pub h: i64,
}

const SCALE: i64 = 2;
const BAR_W: i64 = 26;
const BAR_GAP: i64 = 4;
const GROUP_PAD: i64 = 36;
const MARGIN_LEFT: i64 = 80;
const MARGIN_RIGHT: i64 = 24;
const TITLE_H: i64 = 34;
const LEGEND_ROW_H: i64 = 24;
const PLOT_H: i64 = 300;
const VALUE_LABEL_H: i64 = 14;
const BOTTOM_H: i64 = 48;

/// The y-axis maximum for values up to `max`: a multiple of the tick step
/// (10 or 20 %), at least 10, at most 100 when `max <= 100`.
fn axis_max(max: f64) -> (f64, f64) {
    let step = if max > 50.0 { 20.0 } else { 10.0 };
    let top = ((max / step).ceil() * step).max(10.0);
    (top, step)
}

/// Draws a grouped bar chart of percentages: `values[group][series]` (`None`: no bar).
pub fn grouped_bar_chart(
    title: &str,
    groups: &[String],
    series: &[(String, Rgb)],
    values: &[Vec<Option<f64>>],
) -> (Canvas, Vec<Bar>) {
    let label_w = groups
        .iter()
        .map(|g| Canvas::text_width(g, SCALE))
        .max()
        .unwrap_or(0);
    let bars_w = series.len() as i64 * (BAR_W + BAR_GAP) - BAR_GAP;
    let group_w = bars_w.max(label_w) + GROUP_PAD;
    let plot_w = group_w * groups.len().max(1) as i64;

    // Legend: colour swatch and name, wrapped into rows.
    let legend_items: Vec<i64> = series
        .iter()
        .map(|(name, _)| 16 + 6 + Canvas::text_width(name, SCALE) + 20)
        .collect();
    let content_w = plot_w
        .max(Canvas::text_width(title, SCALE).max(legend_items.iter().copied().max().unwrap_or(0)));
    let width = MARGIN_LEFT + content_w + MARGIN_RIGHT;
    let mut legend_rows = 1;
    let mut x = 0;
    for &w in &legend_items {
        if x > 0 && x + w > content_w {
            legend_rows += 1;
            x = 0;
        }
        x += w;
    }
    let plot_top = TITLE_H + legend_rows * LEGEND_ROW_H + VALUE_LABEL_H + 8;
    let height = plot_top + PLOT_H + BOTTOM_H;
    let mut canvas = Canvas::new(width as usize, height as usize);
    canvas.text(MARGIN_LEFT, 10, title, SCALE, BLACK);

    let (mut lx, mut ly) = (MARGIN_LEFT, TITLE_H);
    for ((name, colour), &w) in series.iter().zip(&legend_items) {
        if lx > MARGIN_LEFT && lx + w > MARGIN_LEFT + content_w {
            lx = MARGIN_LEFT;
            ly += LEGEND_ROW_H;
        }
        canvas.fill_rect(lx, ly, 16, 14, *colour);
        canvas.text(lx + 22, ly, name, SCALE, BLACK);
        lx += w;
    }

    let max = values
        .iter()
        .flatten()
        .flatten()
        .copied()
        .fold(0.0_f64, f64::max);
    let (top, step) = axis_max(max);
    let baseline = plot_top + PLOT_H;
    let y_of = |v: f64| baseline - (v / top * PLOT_H as f64).round() as i64;

    // Grid lines and tick labels (percent).
    let mut tick = 0.0;
    while tick <= top + 1e-9 {
        let y = y_of(tick);
        canvas.fill_rect(MARGIN_LEFT, y, plot_w, 1, GRID);
        canvas.fill_rect(MARGIN_LEFT - 6, y, 6, 1, BLACK);
        let label = format!("{tick:.0}");
        canvas.text(
            MARGIN_LEFT - 10 - Canvas::text_width(&label, SCALE),
            y - 7,
            &label,
            SCALE,
            BLACK,
        );
        tick += step;
    }
    canvas.text(8, plot_top - VALUE_LABEL_H - 4, "%", SCALE, BLACK);

    let mut bars = Vec::new();
    for (g, name) in groups.iter().enumerate() {
        let gx = MARGIN_LEFT + g as i64 * group_w + GROUP_PAD / 2;
        let inner = group_w - GROUP_PAD;
        let bx0 = gx + (inner - bars_w) / 2;
        for (s, (_, colour)) in series.iter().enumerate() {
            let Some(v) = values.get(g).and_then(|row| row.get(s)).copied().flatten() else {
                continue;
            };
            let x = bx0 + s as i64 * (BAR_W + BAR_GAP);
            let y = y_of(v);
            canvas.fill_rect(x, y, BAR_W, baseline - y, *colour);
            let label = if (v - v.round()).abs() < 0.05 {
                format!("{v:.0}")
            } else {
                format!("{v:.1}")
            };
            canvas.text_centred(x + BAR_W / 2, y - 10, &label, 1, BLACK);
            bars.push(Bar {
                group: g,
                series: s,
                x,
                y,
                w: BAR_W,
                h: baseline - y,
            });
        }
        canvas.text_centred(gx + inner / 2, baseline + 14, name, SCALE, BLACK);
    }
    // Axes.
    canvas.fill_rect(MARGIN_LEFT, baseline, plot_w, 2, BLACK);
    canvas.fill_rect(MARGIN_LEFT - 2, plot_top, 2, PLOT_H + 2, BLACK);
    (canvas, bars)
}

/// Grade rates per method: groups = methods, bars = success / partial / failure.
pub fn outcome_chart(report: &Report) -> (Canvas, Vec<Bar>) {
    let groups: Vec<String> = report.methods.iter().map(|m| m.method.clone()).collect();
    let series: Vec<(String, Rgb)> = ["success", "partial", "failure"]
        .iter()
        .zip(GRADE_COLOURS)
        .map(|(n, c)| (n.to_string(), c))
        .collect();
    let values: Vec<Vec<Option<f64>>> = report
        .methods
        .iter()
        .map(|m| vec![m.success_pct, m.partial_pct, m.failure_pct])
        .collect();
    grouped_bar_chart(
        "GRASP OUTCOMES, % OF GRADED TRIALS",
        &groups,
        &series,
        &values,
    )
}

/// Failures by cause (the paper's Table 2): groups = causes and total, bars = methods.
pub fn cause_chart(report: &Report) -> (Canvas, Vec<Bar>) {
    let table = &report.failure_causes;
    let groups: Vec<String> = table
        .rows
        .iter()
        .chain(std::iter::once(&table.total))
        .map(|r| match r.cause.as_str() {
            "shape-dissimilarity" => "shape".to_string(),
            "reachability" => "reach".to_string(),
            "registration" => "regist.".to_string(),
            "execution" => "exec.".to_string(),
            other => other.to_string(),
        })
        .collect();
    let series: Vec<(String, Rgb)> = table
        .methods
        .iter()
        .enumerate()
        .map(|(i, m)| (m.clone(), METHOD_COLOURS[i % METHOD_COLOURS.len()]))
        .collect();
    let values: Vec<Vec<Option<f64>>> = table
        .rows
        .iter()
        .chain(std::iter::once(&table.total))
        .map(|r| r.percent.clone())
        .collect();
    grouped_bar_chart(
        "FAILURES BY CAUSE, % OF ALL GRADED TRIALS",
        &groups,
        &series,
        &values,
    )
}

/// Writes `outcomes.png` and `failure_causes.png` into `dir` (created if needed);
/// returns their paths.
pub fn write_charts(report: &Report, dir: &Path) -> Result<Vec<std::path::PathBuf>, TrialError> {
    crate::fsio::create_dir_all(dir)?;
    let mut written = Vec::new();
    for (name, (canvas, _)) in [
        ("outcomes.png", outcome_chart(report)),
        ("failure_causes.png", cause_chart(report)),
    ] {
        let path = dir.join(name);
        canvas.save_png(&path)?;
        written.push(path);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (usize, usize, Vec<u8>) {
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb);
        buf.truncate(info.buffer_size());
        (info.width as usize, info.height as usize, buf)
    }

    #[test]
    fn glyphs_are_five_columns_and_unique() {
        for (c, rows) in FONT {
            assert!(rows.iter().all(|r| *r < 32), "{c}");
        }
        for (i, (a, ra)) in FONT.iter().enumerate() {
            for (b, rb) in &FONT[i + 1..] {
                assert!(a != b && (ra != rb || *a == ' '), "{a} {b}");
            }
        }
        assert_eq!(glyph('a'), glyph('A'));
        assert_eq!(glyph('~'), glyph('?'));
    }

    #[test]
    fn bars_in_the_png_are_proportional_to_the_values() {
        let groups = vec!["one".to_string(), "two".to_string()];
        let series = vec![
            ("x".to_string(), [10, 20, 30]),
            ("y".to_string(), [200, 100, 50]),
        ];
        let values = vec![vec![Some(60.0), Some(15.0)], vec![Some(30.0), None]];
        let (canvas, bars) = grouped_bar_chart("TEST", &groups, &series, &values);
        assert_eq!(bars.len(), 3);
        let bytes = canvas.to_png(Path::new("test.png")).unwrap();
        let (w, h, rgb) = decode(&bytes);
        assert_eq!((w, h), (canvas.width, canvas.height));
        let at = |x: usize, y: usize| -> Rgb {
            let i = 3 * (y * w + x);
            [rgb[i], rgb[i + 1], rgb[i + 2]]
        };
        // Count each bar's colour down its centre column of the plot area in the
        // decoded image (the legend above uses the same colours).
        let baseline = (bars[0].y + bars[0].h) as usize;
        let plot = baseline - PLOT_H as usize - 1..baseline.min(h);
        let heights: Vec<usize> = bars
            .iter()
            .map(|b| {
                let colour = series[b.series].1;
                let x = (b.x + b.w / 2) as usize;
                plot.clone().filter(|&y| at(x, y) == colour).count()
            })
            .collect();
        // 60 : 15 : 30 within a pixel; the axis top is 60 -> full plot height.
        let unit = heights[0] as f64 / 60.0;
        assert!(
            (heights[1] as f64 - 15.0 * unit).abs() <= 1.0,
            "{heights:?}"
        );
        assert!(
            (heights[2] as f64 - 30.0 * unit).abs() <= 1.0,
            "{heights:?}"
        );
        assert_eq!(heights[0] as i64, PLOT_H);
        // All bars stand on the same baseline.
        assert!(bars.iter().all(|b| b.y + b.h == bars[0].y + bars[0].h));
        // The legend swatches are drawn.
        assert!(rgb.chunks(3).any(|p| p == [200, 100, 50]));
    }

    #[test]
    fn axis_max_rounds_up_to_ticks() {
        assert_eq!(axis_max(0.0), (10.0, 10.0));
        assert_eq!(axis_max(43.0), (50.0, 10.0));
        assert_eq!(axis_max(78.0), (80.0, 20.0));
        assert_eq!(axis_max(100.0), (100.0, 20.0));
    }
}
