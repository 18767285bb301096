//! Property: a bar chart of n bars has exactly n bar labels, each on its bar's
//! row and naming that bar (the diagnose report once showed 10 bars with 11
//! labels, every bar named after its neighbour).
use proptest::prelude::*;
use tofprox_chart::{Bar, BarChart, bar_chart};

fn attr(el: &str, name: &str) -> String {
    el.split(&format!(" {name}=\""))
        .nth(1)
        .unwrap()
        .split('"')
        .next()
        .unwrap()
        .to_string()
}

fn elements<'a>(svg: &'a str, class: &str) -> Vec<&'a str> {
    svg.split(&format!("class=\"{class}\""))
        .skip(1)
        .map(|s| s.split('>').next().unwrap())
        .collect()
}

fn texts(svg: &str, class: &str) -> Vec<(f64, String)> {
    svg.split(&format!("<text class=\"{class}\""))
        .skip(1)
        .map(|s| {
            let y: f64 = attr(s, "y").parse().unwrap();
            let t = s
                .split('>')
                .nth(1)
                .unwrap()
                .split('<')
                .next()
                .unwrap()
                .to_string();
            (y, t)
        })
        .collect()
}

proptest! {
    #[test]
    fn n_bars_have_n_labels_on_their_rows(
        values in prop::collection::vec(prop_oneof![0.0f64..30_000.0, Just(f64::NAN), -5.0f64..0.0], 0..16),
        threshold in prop::option::of(0.0f64..50.0),
    ) {
        let bars: Vec<Bar> = values.iter().enumerate()
            .map(|(i, v)| Bar { label: format!("cond_{i}_x"), value: *v })
            .collect();
        let svg = bar_chart(&BarChart {
            title: "t".into(),
            value_label: "z".into(),
            bars: bars.clone(),
            threshold: threshold.map(|t| (t, "noise".to_string())),
        });
        let rects = elements(&svg, "bar");
        let labels = texts(&svg, "bar-label");
        prop_assert_eq!(rects.len(), bars.len());
        prop_assert_eq!(labels.len(), bars.len());
        prop_assert!(!svg.contains("NaN"));
        for (b, r) in bars.iter().zip(&rects) {
            prop_assert_eq!(&attr(r, "data-label"), &b.label);
            let y: f64 = attr(r, "y").parse().unwrap();
            let h: f64 = attr(r, "height").parse().unwrap();
            let on_row: Vec<&(f64, String)> = labels.iter().filter(|(ly, _)| *ly - 4.0 >= y && *ly - 4.0 <= y + h).collect();
            prop_assert_eq!(on_row.len(), 1);
            prop_assert_eq!(&on_row[0].1, &b.label);
        }
    }
}
