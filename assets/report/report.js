// aift report: draws the page's time series with uPlot (vendored). Every plot that is drawn is
// counted in <body data-plots-drawn>, every failure in data-plot-errors, so a headless browser
// can check the page; the static SVG plots count as drawn when they hold shapes.
(function () {
  "use strict";
  var body = document.body;
  var drawn = 0, failed = 0;
  window.aiftPlots = [];
  var palette = ["#0969da", "#cf222e", "#1a7f37", "#8250df", "#bf8700", "#1b7c83", "#e16f24", "#6e7781", "#a40e26", "#4d2d00"];
  function markFaults(u, marks) {
    var ctx = u.ctx;
    ctx.save();
    ctx.strokeStyle = "#cf222e";
    ctx.setLineDash([5, 4]);
    ctx.lineWidth = 1.5 * (window.devicePixelRatio || 1);
    marks.forEach(function (t) {
      if (t < u.scales.x.min || t > u.scales.x.max) return;
      var x = Math.round(u.valToPos(t, "x", true));
      ctx.beginPath();
      ctx.moveTo(x, u.bbox.top);
      ctx.lineTo(x, u.bbox.top + u.bbox.height);
      ctx.stroke();
    });
    ctx.restore();
  }
  // Tick labels that stay distinct at any range: uPlot's default (the browser's number format,
  // three decimals) prints 0.0012 and 0.0014 both as "0.001". Fixed decimals from the tick step
  // for ordinary magnitudes, else scientific notation; more digits until no two labels agree.
  function tickLabels(u, splits, axisIdx, space, incr) {
    var shown = splits.filter(function (v) { return v != null; });
    var big = shown.some(function (v) { return v !== 0 && (Math.abs(v) < 1e-3 || Math.abs(v) >= 1e5); });
    function distinct(labels) {
      var seen = {};
      for (var i = 0; i < labels.length; i++) {
        if (labels[i] === "") continue;
        if (seen[labels[i]]) return false;
        seen[labels[i]] = true;
      }
      return true;
    }
    var decimals = 0;
    if (!big && incr > 0 && isFinite(incr)) {
      decimals = Math.max(0, Math.ceil(-Math.log10(incr) - 1e-9));
      while (decimals < 15 && Math.abs(Math.round(incr * Math.pow(10, decimals)) - incr * Math.pow(10, decimals)) > 1e-6) decimals += 1;
    }
    for (var extra = 0; extra < 16; extra++) {
      var labels = splits.map(function (v) {
        if (v == null) return "";
        if (v === 0) return "0";
        return big ? v.toExponential(extra) : v.toFixed(Math.min(decimals + extra, 20));
      });
      if (distinct(labels)) return labels;
    }
    return splits.map(function (v) { return v == null ? "" : String(v); });
  }
  window.aiftTickLabels = tickLabels;
  function draw(spec, data) {
    var el = document.getElementById(spec.id);
    var x = data.columns[data.x];
    var series = [{ label: "t (s)" }];
    var values = [x];
    spec.series.forEach(function (s, i) {
      var col = s.column ? data.columns[s.column] : s.values;
      values.push(col);
      series.push({ label: s.label, stroke: s.color || palette[i % palette.length], width: s.width || 1.25, dash: s.dash, spanGaps: false });
    });
    var width = Math.max(320, Math.min(el.clientWidth || 560, 1160));
    var opts = {
      title: spec.title, width: width, height: spec.height || 260, series: series,
      scales: { x: { time: false }, y: spec.ylog ? { distr: 3 } : (spec.yrange ? { range: spec.yrange } : {}) },
      axes: [{ label: "t (s)", values: tickLabels }, { label: spec.ylabel || "", values: tickLabels, size: 70 }],
      cursor: { drag: { x: true, y: false } },
      legend: { live: true },
      hooks: { draw: [function (u) { markFaults(u, data.faults || []); }] }
    };
    var plot = new uPlot(opts, values, el);
    window.aiftPlots.push(plot);
    if (plot.ctx && plot.ctx.canvas && plot.ctx.canvas.width > 0) { drawn += 1; el.dataset.drawn = "1"; }
    else { failed += 1; }
  }
  try {
    var data = JSON.parse(document.getElementById("aift-data").textContent);
    (data.plots || []).forEach(function (spec) {
      try { draw(spec, data); } catch (e) { failed += 1; console.error("plot " + spec.id + ": " + e); }
    });
  } catch (e) { failed += 1; console.error("report data: " + e); }
  document.querySelectorAll("svg.static").forEach(function (svg) {
    if (svg.querySelector("rect, path, circle, line, polyline, text")) { drawn += 1; svg.dataset.drawn = "1"; }
    else { failed += 1; }
  });
  // Images (heatmaps, as data URIs) count once they have loaded.
  var images = document.querySelectorAll("img.static");
  var pending = images.length;
  function finish() {
    body.dataset.plotsDrawn = String(drawn);
    body.dataset.plotErrors = String(failed);
  }
  images.forEach(function (img) {
    var settled = false;
    function done() {
      if (settled) return;
      settled = true;
      if (img.naturalWidth > 0) { drawn += 1; img.dataset.drawn = "1"; } else { failed += 1; console.error("image " + img.alt + " did not load"); }
      pending -= 1;
      if (pending === 0) finish();
    }
    if (img.complete) done();
    else { img.addEventListener("load", done); img.addEventListener("error", done); }
  });
  if (pending === 0) finish();
})();
