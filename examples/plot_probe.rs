use plotters::prelude::*;
fn main() {
    let root = SVGBackend::new("/tmp/pt/probe.svg", (640, 400)).into_drawing_area();
    root.fill(&WHITE).unwrap();
    let mut chart = ChartBuilder::on(&root)
        .caption("joint angles", ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(40)
        .build_cartesian_2d(0f64..20f64, -2f64..1f64)
        .unwrap();
    chart.configure_mesh().x_desc("t (s)").draw().unwrap();
    chart
        .draw_series(LineSeries::new(
            (0..200).map(|i| (i as f64 * 0.1, (i as f64 * 0.1).sin())),
            &RED,
        ))
        .unwrap()
        .label("q1")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
    chart.configure_series_labels().draw().unwrap();
    root.present().unwrap();
}
