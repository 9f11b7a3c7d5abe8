/* motion-zoo site: tables (switches, sorting, per-action view), error curves and training
   curves, drawn as SVG from the numbers inlined in each page. No network, no library. */
"use strict";
var ZooSite = (function () {
  // zoo.report.outputs.PALETTE, passed by the page: every model has its own colour, on every page and plot
  var COLOURS = window.ZOO_PALETTE_COLOURS || ["#1f77b4"];
  var MARKERS = ["circle", "square", "triangle", "diamond", "cross", "down"];
  var SVG = "http://www.w3.org/2000/svg";

  // a row's model (row.base, named by the site builder) fixes its colour and marker on every
  // page; its @last variant and autoencoder floor are dashed
  function style(row) {
    var names = window.ZOO_PALETTE_MODELS || [];
    var i = names.indexOf(row.base);
    if (i < 0) {  // outside the registry: by its letters, as zoo.report.outputs.model_style
      i = 0;
      for (var c = 0; c < row.base.length; c++) { i += row.base.charCodeAt(c); }
    }
    return {colour: COLOURS[i % COLOURS.length],
            marker: MARKERS[i % MARKERS.length],
            dashed: !!row.variant || !!row.floor};
  }

  function el(tag, attrs, text) {
    var e = document.createElement(tag);
    for (var k in (attrs || {})) { e.setAttribute(k, attrs[k]); }
    if (text !== undefined) { e.textContent = text; }
    return e;
  }

  function svgEl(tag, attrs) {
    var e = document.createElementNS(SVG, tag);
    for (var k in attrs) { e.setAttribute(k, attrs[k]); }
    return e;
  }

  // The interval and bold paragraphs are written with Markdown's **, * and `: shown as such
  // (the bold and italic words name the table's two marks, drawn as its cells draw them).
  function richText(node, text) {
    node.textContent = "";
    var parts = String(text).split(/(\*\*[^*]+\*\*|\*[^*\s][^*]*\*|`[^`]+`)/);
    parts.forEach(function (p) {
      if (/^\*\*.*\*\*$/.test(p)) { node.appendChild(el("strong", {"class": "mark-lowest"}, p.slice(2, -2))); }
      else if (/^\*.*\*$/.test(p)) { node.appendChild(el("em", {"class": "mark-tied"}, p.slice(1, -1))); }
      else if (/^`.*`$/.test(p)) { node.appendChild(el("code", {}, p.slice(1, -1))); }
      else if (p) { node.appendChild(document.createTextNode(p)); }
    });
  }

  function format(value, fmt) {
    if (value === null || value === undefined) { return "–"; }
    var m = /^\.(\d+)([fg])$/.exec(fmt || ".2f");
    if (!m) { return String(value); }
    return m[2] === "f" ? value.toFixed(+m[1]) : String(+value.toPrecision(+m[1]));
  }

  function niceTicks(lo, hi, count) {
    var span = hi - lo || 1, step = Math.pow(10, Math.floor(Math.log10(span / count)));
    [1, 2, 5, 10].some(function (f) { if (span / (step * f) <= count) { step *= f; return true; } return false; });
    var ticks = [];
    for (var t = Math.ceil(lo / step) * step; t <= hi + 1e-9 * span; t += step) { ticks.push(+t.toPrecision(12)); }
    return ticks;
  }

  function marker(g, kind, x, y, colour) {
    var s = 3.5, shape;
    if (kind === "square") { shape = svgEl("rect", {x: x - s, y: y - s, width: 2 * s, height: 2 * s}); }
    else if (kind === "triangle") { shape = svgEl("polygon", {points: [x, y - s, x - s, y + s, x + s, y + s].join(" ")}); }
    else if (kind === "down") { shape = svgEl("polygon", {points: [x, y + s, x - s, y - s, x + s, y - s].join(" ")}); }
    else if (kind === "diamond") { shape = svgEl("polygon", {points: [x, y - s, x + s, y, x, y + s, x - s, y].join(" ")}); }
    else if (kind === "cross") { shape = svgEl("path", {d: "M" + (x - s) + " " + (y - s) + "L" + (x + s) + " " + (y + s) + "M" + (x - s) + " " + (y + s) + "L" + (x + s) + " " + (y - s), "stroke-width": 2}); }
    else { shape = svgEl("circle", {cx: x, cy: y, r: s}); }
    shape.setAttribute("fill", colour); shape.setAttribute("stroke", colour);
    g.appendChild(shape);
  }

  /* series: [{label, points: [[x, y], ...], style}]; draws into container (replacing it).
     Clicking a legend entry hides or shows its curve (kept across redraws of the container),
     and the y range follows the curves shown. */
  var chartCount = 0;
  function logTicks(lo, hi) {  // 1, 2, 5 times each power of ten from 10^lo to 10^hi
    var ticks = [];
    for (var k = lo; k <= hi; k++) { [1, 2, 5].forEach(function (m) { var v = m * Math.pow(10, k); if (Math.log10(v) <= hi + 1e-9) { ticks.push(+v.toPrecision(6)); } }); }
    return ticks;
  }
  function lineChart(container, series, xLabel, yLabel, title) {
    container.textContent = "";
    var hidden = container.hiddenSeries || (container.hiddenSeries = {});
    var W = 760, L = 64, R = 230, T = 30, B = 46;
    var H = Math.max(380, T + B + 17 * series.length);  // room for every legend entry
    var xs = [], ys = [];
    var drawn = series.filter(function (s) { return !hidden[s.label]; });
    (drawn.length ? drawn : series).forEach(function (s) { s.points.forEach(function (p) { if (p[1] !== null) { xs.push(p[0]); ys.push(p[1]); } }); });
    if (!xs.length) { container.appendChild(el("p", {"class": "note"}, "No values to draw.")); return; }
    var x0 = Math.min.apply(null, xs), x1 = Math.max.apply(null, xs);
    // a log scale where the container asks for one and every value is positive
    var log = container.logScale && Math.min.apply(null, ys) > 0;
    var f = log ? Math.log10 : function (y) { return y; };
    var y0 = log ? Math.floor(f(Math.min.apply(null, ys))) : Math.min(0, Math.min.apply(null, ys));
    var y1 = log ? Math.ceil(f(Math.max.apply(null, ys))) : Math.max.apply(null, ys) * 1.05;
    var sx = function (x) { return L + (x - x0) / ((x1 - x0) || 1) * (W - L - R); };
    var sy = function (y) { return H - B - (f(y) - y0) / ((y1 - y0) || 1) * (H - T - B); };
    var yTicks = log ? logTicks(y0, y1) : niceTicks(y0, y1, 6);
    var svg = svgEl("svg", {viewBox: "0 0 " + W + " " + H, width: "100%", role: "img", "aria-label": title});
    var t = svgEl("text", {x: L, y: 18, "class": "title"}); t.textContent = title; svg.appendChild(t);
    yTicks.forEach(function (v) {
      svg.appendChild(svgEl("line", {x1: L, x2: W - R, y1: sy(v), y2: sy(v), "class": "grid"}));
      var lab = svgEl("text", {x: L - 6, y: sy(v) + 4, "text-anchor": "end", "class": "tick"}); lab.textContent = String(v); svg.appendChild(lab);
    });
    niceTicks(x0, x1, 8).forEach(function (v) {
      var lab = svgEl("text", {x: sx(v), y: H - B + 16, "text-anchor": "middle", "class": "tick"}); lab.textContent = String(v); svg.appendChild(lab);
    });
    svg.appendChild(svgEl("line", {x1: L, x2: W - R, y1: H - B, y2: H - B, "class": "axis"}));
    svg.appendChild(svgEl("line", {x1: L, x2: L, y1: T, y2: H - B, "class": "axis"}));
    var xl = svgEl("text", {x: (L + W - R) / 2, y: H - 8, "text-anchor": "middle", "class": "label"}); xl.textContent = xLabel; svg.appendChild(xl);
    // a long unit (RMSE's) does not fit beside the axis: the metric there, the whole in a tooltip
    var shortY = yLabel.length > 40 ? yLabel.split(" (")[0] : yLabel;
    var yl = svgEl("text", {x: 14, y: (T + H - B) / 2, transform: "rotate(-90 14 " + (T + H - B) / 2 + ")", "text-anchor": "middle", "class": "label"}); yl.textContent = shortY;
    var yTip = svgEl("title"); yTip.textContent = yLabel; yl.appendChild(yTip); svg.appendChild(yl);
    var clip = "plot-area-" + (chartCount += 1);  // curves stay inside the axes
    svg.appendChild(svgEl("clipPath", {id: clip})).appendChild(svgEl("rect", {x: L, y: T - 4, width: W - L - R, height: H - T - B + 8}));
    series.forEach(function (s, i) {
      if (!hidden[s.label]) {
        var g = svgEl("g", {"class": "series", "data-series": s.label, "clip-path": "url(#" + clip + ")"});
        var pts = s.points.filter(function (p) { return p[1] !== null; });
        var d = pts.map(function (p, j) { return (j ? "L" : "M") + sx(p[0]).toFixed(1) + " " + sy(p[1]).toFixed(1); }).join("");
        g.appendChild(svgEl("path", {d: d, fill: "none", stroke: s.style.colour, "stroke-width": 1.8, "stroke-dasharray": s.style.dashed ? "5 3" : "none"}));
        var every = Math.max(1, Math.round(pts.length / 10));
        pts.forEach(function (p, j) { if (j % every === 0 || j === pts.length - 1) { marker(g, s.style.marker, sx(p[0]), sy(p[1]), s.style.colour); } });
        svg.appendChild(g);
      }
      var ly = T + 8 + i * 17;
      var entry = svgEl("g", {"class": "legend-entry" + (hidden[s.label] ? " hidden" : ""), "data-series": s.label});
      var tip = svgEl("title"); tip.textContent = (hidden[s.label] ? "show " : "hide ") + s.label; entry.appendChild(tip);
      entry.appendChild(svgEl("rect", {x: W - R + 8, y: ly - 8, width: R - 12, height: 16, fill: "transparent"}));
      entry.appendChild(svgEl("line", {x1: W - R + 12, x2: W - R + 34, y1: ly, y2: ly, stroke: s.style.colour, "stroke-width": 1.8, "stroke-dasharray": s.style.dashed ? "5 3" : "none"}));
      marker(entry, s.style.marker, W - R + 23, ly, s.style.colour);
      var lt = svgEl("text", {x: W - R + 40, y: ly + 4, "class": "legend"}); lt.textContent = s.label; entry.appendChild(lt);
      entry.addEventListener("click", function () {
        hidden[s.label] = !hidden[s.label];
        lineChart(container, series, xLabel, yLabel, title);
      });
      svg.appendChild(entry);
    });
    container.appendChild(svg);
  }

  function table(data) {
    var summary = data.summary;
    if (!summary || !summary.views || !summary.views.length) { return; }
    var views = summary.views, costs = data.costs || {};
    var state = {view: views[0], action: "average", sort: null, descending: false, last: false,
                 horizons: "key", costs: false, sources: false};
    // a view lives in the page's fragment (#metric=...&sort=7), so that it can be sent and reopened
    function readFragment() {
      var f = {};
      location.hash.replace(/^#/, "").split("&").forEach(function (kv) {
        var i = kv.indexOf("="); if (i > 0) { f[decodeURIComponent(kv.slice(0, i))] = decodeURIComponent(kv.slice(i + 1)); }
      });
      var v = views.filter(function (x) {
        return (!f.metric || x.metric === f.metric) && (!f.averaging || x.averaging === f.averaging) && (!f.joints || x.joints === f.joints);
      })[0];
      if (v) { state.view = v; }
      if (f.action && (f.action === "average" || summary.actions.indexOf(f.action) >= 0)) { state.action = f.action; }
      if (f.sort === "model") { state.sort = "model"; }
      else if (f.sort !== undefined && /^\d+$/.test(f.sort) && +f.sort < state.view.horizons_ms.length) { state.sort = +f.sort; }
      state.descending = f.desc === "1"; state.last = f.last === "1";
      state.horizons = f.h === "all" ? "all" : "key"; state.costs = f.costs === "1"; state.sources = f.src === "1";
    }
    function writeFragment() {
      var v = state.view;
      var parts = {metric: v.metric, averaging: v.averaging, joints: v.joints, action: state.action,
                   sort: state.sort === null ? "" : String(state.sort), desc: state.descending ? "1" : "0",
                   last: state.last ? "1" : "0", h: state.horizons, costs: state.costs ? "1" : "0",
                   src: state.sources ? "1" : "0"};
      var text = Object.keys(parts).map(function (k) { return k + "=" + encodeURIComponent(parts[k]); }).join("&");
      if (history.replaceState) { history.replaceState(null, "", "#" + text); } else { location.hash = text; }
    }
    // the horizons shown by default: the first, the one nearest 400 ms and the last
    function keyHorizons(v) { return v.key_horizons; }  // zoo.site.collect.key_horizons
    function shown(i) { return state.horizons === "all" || keyHorizons(state.view).indexOf(i) >= 0; }
    var $ = function (id) { return document.getElementById(id); };
    function unique(list) { return list.filter(function (v, i) { return list.indexOf(v) === i; }); }
    function fill(select, values, chosen) {
      select.textContent = "";
      values.forEach(function (v) { var o = el("option", {value: v}, v); if (v === chosen) { o.selected = true; } select.appendChild(o); });
    }
    function pick(changed) {
      var want = {metric: $("metric").value, averaging: $("averaging").value, joints: $("joints").value};
      // keep what was changed; among the views that have it, the one that keeps most of the
      // other choices, the averaging before the joints
      var best = null, score = -1;
      views.forEach(function (v) {
        if (v[changed] !== want[changed]) { return; }
        var s = (v.metric === want.metric) * 4 + (v.averaging === want.averaging) * 2 + (v.joints === want.joints);
        if (s > score) { best = v; score = s; }
      });
      state.view = best || views[0];
      if (state.sort !== null && state.sort !== "model" && state.sort >= state.view.horizons_ms.length) { state.sort = null; }
      render();
    }
    function controls() {
      var v = state.view;
      fill($("metric"), unique(views.map(function (x) { return x.metric; })), v.metric);
      fill($("averaging"), unique(views.filter(function (x) { return x.metric === v.metric; }).map(function (x) { return x.averaging; })), v.averaging);
      fill($("joints"), unique(views.filter(function (x) { return x.metric === v.metric && x.averaging === v.averaging; }).map(function (x) { return x.joints; })), v.joints);
      fill($("action"), ["average"].concat(summary.actions), state.action);
      $("show-last").checked = state.last; $("show-costs").checked = state.costs; $("show-sources").checked = state.sources;
      var keys = keyHorizons(v).map(function (i) { return v.horizons_ms[i]; }).join(", ");
      fill($("horizons"), ["key", "all"], state.horizons);
      $("horizons").options[0].textContent = keys + " ms"; $("horizons").options[1].textContent = "all " + v.horizons_ms.length;
    }
    // every action beside every other, as papers print them: the rows of the table above, in
    // its order, an action's shown horizons side by side
    function perAction(rows, v) {
      var box = $("per-action"); box.textContent = "";
      var hs = v.horizons_ms.map(function (h, i) { return i; }).filter(shown), fmt = v.format;
      var table = el("table", {"class": "board per-action"}), thead = el("thead");
      var top = el("tr"); top.appendChild(el("th", {"class": "model", rowspan: "2"}, "model"));
      summary.actions.forEach(function (a) { top.appendChild(el("th", {colspan: String(hs.length), "class": "action"}, a)); });
      var second = el("tr");
      summary.actions.forEach(function () { hs.forEach(function (i) { second.appendChild(el("th", {"class": "num"}, v.horizons_ms[i] + " ms")); }); });
      thead.appendChild(top); thead.appendChild(second); table.appendChild(thead);
      var body = el("tbody");
      function line(name, perAction, cls) {
        var tr = el("tr", {"data-model": name, "class": cls || ""});
        tr.appendChild(el("td", {"class": "model"}, name));
        summary.actions.forEach(function (a) {
          var values = (perAction || {})[a] || [];
          hs.forEach(function (i) {
            var value = values[i] === undefined ? null : values[i];
            tr.appendChild(el("td", {"class": "num", "data-action": a, "data-horizon": String(v.horizons_ms[i])}, format(value, fmt)));
          });
        });
        body.appendChild(tr);
      }
      rows.forEach(function (r) { line(r.model, r.per_action); });
      (v.reported || []).forEach(function (p) { if (p.per_action) { line(p.label, p.per_action, "reported"); } });
      table.appendChild(body); box.appendChild(table);
    }
    function csv(rows) {
      // the rows shown, every horizon of the view, with the table's protocol id
      var v = state.view, head = ["protocol_id", "metric", "averaging", "joints", "action", "model"];
      v.horizons_ms.forEach(function (h) { head.push(h + "_ms"); });
      var lines = [head.join(",")];
      rows.forEach(function (r) {
        var line = [summary.protocol_id, v.metric, v.averaging, v.joints, state.action, r.model];
        v.horizons_ms.forEach(function (h, i) { var c = cell(r, i).value; line.push(c === null ? "" : String(c)); });
        lines.push(line.join(","));
      });
      return lines.join("\n") + "\n";
    }
    function cell(row, i) {
      var average = state.action === "average";
      var value = average ? row.values[i] : ((row.per_action || {})[state.action] || [])[i];
      return {value: value === undefined ? null : value,
              half: average && row.half ? row.half[i] : null,
              bold: average && row.bold ? row.bold[i] : false,
              // a table written before "lowest" was stored: its bold cells, as they were
              lowest: average ? (row.lowest || row.bold || [])[i] || false : false};
    }
    function render() {
      var v = state.view, fmt = v.format;
      controls();
      $("protocol-note").textContent = v.metric.toUpperCase() + " (" + v.unit + "), averaging " + v.averaging + ": " + v.averaging_words + (v.joints_words ? ". Joints " + v.joints + ": " + v.joints_words : "") + ". Every row below is this one protocol.";
      richText($("bold-note"), state.action === "average" ? v.interval_words + "." : "Per action: the mean over that action's windows; intervals and bold are computed for the mean over actions only.");
      var rows = v.models.filter(function (r) { return state.last || r.model.indexOf("@last") < 0; });
      if (state.sort === null) { state.sort = v.horizons_ms.length - 1; }  // ranked at the longest horizon
      {
        rows = rows.slice().sort(function (a, b) {
          var x = state.sort === "model" ? a.model : cell(a, state.sort).value;
          var y = state.sort === "model" ? b.model : cell(b, state.sort).value;
          if (x === null || y === null) { return (x === null) - (y === null); }  // empty cells last
          var c = x < y ? -1 : x > y ? 1 : 0;
          return state.descending ? -c : c;
        });
      }
      var board = $("board"); board.textContent = "";
      var ranked = state.sort !== "model";
      var head = el("tr");
      head.appendChild(el("th", {"class": "rank num", "title": ranked ? "rank at " + v.horizons_ms[state.sort] + " ms (ties share a rank)" : ""}, "#"));
      var th = el("th", {"data-key": "model", "class": "sortable model"}, "model"); head.appendChild(th);
      v.horizons_ms.forEach(function (h, i) { head.appendChild(el("th", {"data-key": String(i), "class": "sortable num" + (shown(i) ? "" : " off")}, h + " ms")); });
      ["parameters", "GFLOP / window", "latency (ms)", "training windows / s"].forEach(function (c) { head.appendChild(el("th", {"class": "num cost" + (state.costs ? "" : " off")}, c)); });
      head.appendChild(el("th", {"class": "source" + (state.sources ? "" : " off")}, "computed · to compute it again"));
      var thead = el("thead"); thead.appendChild(head); board.appendChild(thead);
      Array.prototype.forEach.call(head.querySelectorAll("th.sortable"), function (t) {
        var key = t.getAttribute("data-key");
        var mine = String(state.sort) === key || (state.sort === "model" && key === "model");
        if (mine) { t.classList.add(state.descending ? "desc" : "asc"); }
        t.addEventListener("click", function () {
          var k = key === "model" ? "model" : +key;
          state.descending = state.sort === k ? !state.descending : false;
          state.sort = k; render();
        });
      });
      function machineOf(k) { return (k.device || "a machine not recorded") + (k.date ? " (" + k.date + ")" : ""); }
      var machines = unique(Object.keys(costs).map(function (m) { return machineOf(costs[m]); }));
      var body = el("tbody");
      // the observed frames each row read, where the rows did not all read every frame given
      var histories = unique(rows.map(function (r) { return r.history || ""; }));
      var showHistory = histories.length > 1 || histories.some(function (h) { return h && h.indexOf("all ") !== 0; });
      // rank: 1 + how many rows are lower at the sorted horizon (ties share), whatever the order shown
      var scores = ranked ? rows.filter(function (r) { return !r.floor && !r.unranked; }).map(function (r) { return cell(r, state.sort).value; }).filter(function (x) { return x !== null; }) : [];
      rows.forEach(function (r) {
        var tr = el("tr", {"data-model": r.model});
        if (r.floor) { tr.classList.add("floor"); }
        var score = ranked ? cell(r, state.sort).value : null;
        var rank = score === null || r.floor || r.unranked ? "" : String(1 + scores.filter(function (x) { return x < score; }).length);
        tr.appendChild(el("td", {"class": "rank num"}, rank));
        var name = el("td", {"class": "model"});
        var swatch = el("span", {"class": "swatch"}); swatch.style.background = style(r).colour; name.appendChild(swatch);
        var card = (data.pages || []).indexOf("model-" + r.base + ".html") >= 0 ? "model-" + r.base + ".html" : null;
        if (card) { var a = el("a", {href: card}, r.model); name.appendChild(a); }
        else { name.appendChild(document.createTextNode(r.model)); }
        var budget = (data.budgets || {})[r.model];
        if (budget) {  // weights trained short of their recipe: said where the number is
          var tag = el(card ? "a" : "span", {"class": "tag warn short", title: budget}, "short training");
          if (card) { tag.setAttribute("href", card); }
          name.appendChild(tag);
        }
        if (showHistory && r.history) {
          name.appendChild(el("span", {"class": "tag history", title: "observed frames this row's model read"}, "history: " + r.history));
        }
        tr.appendChild(name);
        v.horizons_ms.forEach(function (h, i) {
          var c = cell(r, i);
          var td = el("td", {"class": "num" + (shown(i) ? "" : " off"), "data-horizon": String(h), "data-value": c.value === null ? "" : String(c.value)});
          td.textContent = format(c.value, fmt) + (c.half !== null && c.half !== undefined ? " ±" + format(c.half, fmt) : "");
          // the lowest, and apart from it the rows not distinguishable from it
          if (c.lowest) { td.classList.add("bold"); }
          else if (c.bold) { td.classList.add("tied"); td.title = "not distinguishable from the lowest (what the marks mean: below the table)"; }
          tr.appendChild(td);
        });
        var k = costs[r.model] || {};
        // timings of more than one machine in a column: each timed cell names its machine
        var mark = machines.length > 1 && k.device ? " " + "¹²³⁴⁵⁶⁷⁸⁹"[machines.indexOf(machineOf(k))] : "";
        [k.parameters === "0" ? "0" : k.parameters ? (k.parameters / 1e6).toFixed(3) + " M" : "",
         k.gflop ? (+k.gflop).toPrecision(3) : "", k.latency_ms ? (+k.latency_ms).toPrecision(3) + mark : "",
         k.train_per_s ? (+k.train_per_s).toPrecision(3) + mark : ""].forEach(function (t) { tr.appendChild(el("td", {"class": "num cost" + (state.costs ? "" : " off")}, t)); });
        var src = (data.sources || {})[r.model] || {}, where = el("td", {"class": "source" + (state.sources ? "" : " off")});
        where.appendChild(document.createTextNode((src.created || "") + (src.code ? " · " + src.code : "") + " "));
        if (src.needs) { where.appendChild(el("span", {"class": "needs"}, src.needs + "; then ")); }
        if (src.command) { where.appendChild(el("code", {}, src.command)); }
        tr.appendChild(where);
        body.appendChild(tr);
      });
      (v.reported || []).forEach(function (p) {
        var values = state.action === "average" ? p.values : (p.per_action || {})[state.action];
        if (!values) { return; }
        var tr = el("tr", {"class": "reported", "data-reported": p.label});
        tr.appendChild(el("td", {"class": "rank num"}, ""));
        var label = el("td", {"class": "model", "title": p.source}, p.label);
        label.appendChild(el("span", {"class": "source"}, p.source)); tr.appendChild(label);
        v.horizons_ms.forEach(function (h, i) { tr.appendChild(el("td", {"class": "num" + (shown(i) ? "" : " off")}, format(values[i], fmt))); });
        for (var c = 0; c < 4; c++) { tr.appendChild(el("td", {"class": "num cost" + (state.costs ? "" : " off")}, "–")); }
        tr.appendChild(el("td", {"class": "source" + (state.sources ? "" : " off")}, ""));
        body.appendChild(tr);
      });
      board.appendChild(body);
      perAction(rows, v);
      var stem = (summary.benchmark || "table") + "-" + v.metric + "-" + v.averaging + "-" + v.joints + "-" + state.action;
      var download = $("download");
      download.href = "data:text/csv;charset=utf-8," + encodeURIComponent(csv(rows));
      download.setAttribute("download", stem + ".csv");
      var json = {protocol_id: summary.protocol_id, benchmark: summary.benchmark, metric: v.metric, unit: v.unit,
                  averaging: v.averaging, joints: v.joints, action: state.action, horizons_ms: v.horizons_ms,
                  rows: rows.map(function (r) { return {model: r.model, values: v.horizons_ms.map(function (h, i) { return cell(r, i).value; })}; })};
      $("download-json").href = "data:application/json;charset=utf-8," + encodeURIComponent(JSON.stringify(json, null, 1));
      $("download-json").setAttribute("download", stem + ".json");
      writeFragment();
      $("cost-note").textContent = machines.length ? "Cost columns measured by zoo costs on " + machines.map(function (m, i) { return (machines.length > 1 ? "¹²³⁴⁵⁶⁷⁸⁹"[i] + " " : "") + m; }).join("; ") + ": parameters, forward GFLOPs per window, median latency of one window, training windows per second" + (machines.length > 1 ? "; latencies and training speeds of different machines do not compare" : "") + "." : "No costs stored for this table (zoo costs fills them).";
      var series = rows.filter(function (r) { return !r.floor; }).map(function (r) {
        var points = state.action === "average" ? r.curve : v.horizons_ms.map(function (h, i) { return [h, cell(r, i).value]; });
        return {label: r.model, points: points, style: style(r)};
      });
      var curves = $("curves");
      curves.logScale = $("log-scale").checked;
      curves.hiddenSeries = curves.hiddenSeries || {};
      (data.baselines || []).forEach(function (b) {
        series.forEach(function (s) { if (s.label.split("@")[0] === b) { curves.hiddenSeries[s.label] = $("hide-baselines").checked; } });
      });
      lineChart(curves, series, "horizon (ms)", v.metric.toUpperCase() + " (" + v.unit + ")",
                v.metric.toUpperCase() + ", " + v.averaging + " averaging, joints " + v.joints + ", " + (state.action === "average" ? "mean over actions" : state.action));
      var others = $("reported"); others.textContent = "";
      if ((v.other_protocols || []).length) {
        others.appendChild(el("h2", {}, "Published under other protocols (not comparable with the rows above)"));
        var ul = el("ul");
        v.other_protocols.forEach(function (p) {
          var figures = Object.keys(p.values).map(function (h) { return h + " ms " + format(p.values[h], fmt); }).join(", ");
          ul.appendChild(el("li", {}, p.label + ", " + p.source + ": " + (figures || "no average") + "; differs: " + p.differences.join("; ") + "."));
        });
        others.appendChild(ul);
      }
    }
    ["metric", "averaging", "joints"].forEach(function (id) { $(id).addEventListener("change", function () { pick(id); }); });
    $("action").addEventListener("change", function () { state.action = $("action").value; render(); });
    $("show-last").addEventListener("change", function () { state.last = $("show-last").checked; render(); });
    $("show-costs").addEventListener("change", function () { state.costs = $("show-costs").checked; render(); });
    $("show-sources").addEventListener("change", function () { state.sources = $("show-sources").checked; render(); });
    $("log-scale").addEventListener("change", render);
    $("hide-baselines").addEventListener("change", render);
    $("horizons").addEventListener("change", function () { state.horizons = $("horizons").value; render(); });
    window.addEventListener("hashchange", function () { readFragment(); render(); });
    readFragment();
    render();
  }

  function training(data) {
    var node = document.getElementById("training");
    var keys = Object.keys(data.curves || {});
    if (!keys.length) { node.appendChild(el("p", {"class": "note"}, "No shipped weights record holds a training history.")); return; }
    var series = keys.map(function (k, i) {
      return {label: k, points: data.curves[k], style: {colour: COLOURS[i % COLOURS.length], marker: MARKERS[i % MARKERS.length], dashed: k.indexOf("@") >= 0}};
    });
    lineChart(node, series, "optimizer steps", "validation error (mm)", "validation error while training, per shipped weights file");
  }

  /* the index's models list, filtered by representation, kind and name */
  function modelFilter() {
    var rep = document.getElementById("filter-representation"), kind = document.getElementById("filter-kind");
    var name = document.getElementById("filter-name");
    if (!rep) { return; }
    function apply() {
      Array.prototype.forEach.call(document.querySelectorAll("ul.models li"), function (li) {
        var ok = (!rep.value || li.getAttribute("data-representation").split(" ").indexOf(rep.value) >= 0) &&
                 (!kind.value || li.getAttribute("data-kind") === kind.value) &&
                 li.getAttribute("data-model").indexOf(name.value.trim().toLowerCase()) >= 0;
        li.style.display = ok ? "" : "none";
      });
    }
    [rep, kind].forEach(function (x) { x.addEventListener("change", apply); });
    name.addEventListener("input", apply);
  }

  /* the compare page: any two rows of a table against each other (every pair is on the page,
     the pairs a reader asks about first shown on load); the choice lives in the URL fragment */
  function pairs() {
    var forms = document.querySelectorAll("form.pair-pick");
    function sections(table) {
      return Array.prototype.filter.call(document.querySelectorAll("section.pair"), function (s) { return s.getAttribute("data-table") === table; });
    }
    function show(form, a, b) {
      var table = form.getAttribute("data-table"), status = form.querySelector("[role=status]"), found = false;
      sections(table).forEach(function (s) {
        var sa = s.getAttribute("data-a"), sb = s.getAttribute("data-b");
        var on = a === null ? s.getAttribute("data-reader") === "yes" : (sa === a && sb === b) || (sa === b && sb === a);
        s.hidden = !on;
        found = found || on;
      });
      status.textContent = a === null ? "" : a === b ? "pick two different rows" : found ? "" : "no comparison of " + a + " and " + b + " is stored";
    }
    function fromFragment() {
      var hash = "";
      try { hash = decodeURIComponent(location.hash); } catch (e) { hash = ""; }  // not ours
      var m = /^#pair=([^:]*):([^:]*):(.*)$/.exec(hash);
      Array.prototype.forEach.call(forms, function (form) {
        if (m && form.getAttribute("data-table") === m[1]) {
          form.a.value = m[2]; form.b.value = m[3]; show(form, m[2], m[3]);
        } else { show(form, null, null); }
      });
    }
    Array.prototype.forEach.call(forms, function (form) {
      function picked() {
        var text = "pair=" + [form.getAttribute("data-table"), form.a.value, form.b.value].join(":");
        if (history.replaceState) { history.replaceState(null, "", "#" + encodeURIComponent(text)); } else { location.hash = text; }
        fromFragment();
      }
      form.a.addEventListener("change", picked);
      form.b.addEventListener("change", picked);
      form.reader.addEventListener("click", function () {
        if (history.replaceState) { history.replaceState(null, "", location.pathname + location.search); } else { location.hash = ""; }
        fromFragment();
      });
    });
    window.addEventListener("hashchange", fromFragment);
    fromFragment();
  }

  return {table: table, training: training, style: style, lineChart: lineChart, modelFilter: modelFilter, pairs: pairs};
})();
