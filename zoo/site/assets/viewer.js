/* motion-zoo mesh viewer: the clips of a mesh benchmark (window.ZOO_CLIPS, int16 mm around each
   window's centre) drawn on 2D canvases, flat shaded, painter's order; no WebGL, no library. */
"use strict";
var ZooViewer = (function () {
  function int16(b64) {
    var bytes = atob(b64), buf = new ArrayBuffer(bytes.length), u8 = new Uint8Array(buf);
    for (var i = 0; i < bytes.length; i++) { u8[i] = bytes.charCodeAt(i); }
    return new Int16Array(buf);
  }
  function int32(b64) {
    var bytes = atob(b64), buf = new ArrayBuffer(bytes.length), u8 = new Uint8Array(buf);
    for (var i = 0; i < bytes.length; i++) { u8[i] = bytes.charCodeAt(i); }
    return new Int32Array(buf);
  }
  // error ramp: the ground truth's grey at 0, orange, then red at the top
  var RAMP = [[200, 204, 214], [250, 190, 90], [240, 110, 40], [190, 20, 30]];
  function ramp(t) {
    t = Math.max(0, Math.min(1, t)) * (RAMP.length - 1);
    var i = Math.min(RAMP.length - 2, Math.floor(t)), f = t - i, a = RAMP[i], b = RAMP[i + 1];
    return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
  }

  function start(clips) {
    var V = clips.vertices, T = clips.frames, Tin = clips.input_frames, Tout = T - Tin;
    var faces = int32(clips.faces), F = clips.face_count;
    var truth = int16(clips.truth), preds = {};
    clips.models.forEach(function (m) { preds[m] = int16(clips.predictions[m]); });
    var $ = function (id) { return document.getElementById(id); };
    var state = {window: 0, frame: Tin, playing: false, turn: 30 * Math.PI / 180};
    // per window: the vertical axis (the one its first frame spreads most along), and the box
    // of every frame shown (truth and predictions), so that no frame leaves the canvas
    var up = 2, ext = [1, 1, 1], mid = [0, 0, 0];
    function spread(array, from, count, lo, hi) {
      for (var i = from; i < from + count * 3; i += 3) {
        for (var k = 0; k < 3; k++) { var x = array[i + k]; if (x < lo[k]) { lo[k] = x; } if (x > hi[k]) { hi[k] = x; } }
      }
    }
    function measure(w) {
      var lo = [1e9, 1e9, 1e9], hi = [-1e9, -1e9, -1e9];
      spread(truth, w * T * V * 3, V, lo, hi);
      for (var k = 0; k < 3; k++) { ext[k] = Math.max(hi[k] - lo[k], 1); }
      up = ext.indexOf(Math.max.apply(null, ext));
      lo = [1e9, 1e9, 1e9]; hi = [-1e9, -1e9, -1e9];
      spread(truth, w * T * V * 3, T * V, lo, hi);
      clips.models.forEach(function (m) { spread(preds[m], w * Tout * V * 3, Tout * V, lo, hi); });
      for (k = 0; k < 3; k++) { ext[k] = Math.max(hi[k] - lo[k], 1); mid[k] = (lo[k] + hi[k]) / 2; }
    }
    // one colour scale for the benchmark: a twentieth of the largest body extent of any window
    var top = 1;
    for (var w0 = 0; w0 < clips.windows.length; w0++) { measure(w0); top = Math.max(top, 0.05 * Math.max(ext[0], ext[1], ext[2])); }
    state.window = +$("clip-window").value || 0;  // the first window listed: grouped by action
    measure(state.window);
    // repeat_last: the last observed frame held, the baseline every model must beat
    var panels = [{name: "ground truth", model: null}, {name: "repeat_last", model: null, still: true}].concat(clips.models.map(function (m) { return {name: m, model: m}; }));
    var viewer = $("viewer"); viewer.textContent = "";
    panels.forEach(function (p) {
      var fig = document.createElement("figure");
      p.canvas = document.createElement("canvas"); p.canvas.width = 200; p.canvas.height = 280;
      p.canvas.setAttribute("data-panel", p.name);
      p.caption = document.createElement("figcaption");
      fig.appendChild(p.canvas); fig.appendChild(p.caption); viewer.appendChild(fig);
    });
    var slider = $("frame"); slider.max = String(T - 1);

    function frameOf(array, w, t, frames) { return array.subarray(((w * frames) + t) * V * 3, ((w * frames) + t + 1) * V * 3); }

    // positions on a canvas W x H: turned about the vertical axis, scaled, centred on the box
    function project(pos, W, H, scale) {
      var h1 = (up + 1) % 3, h2 = (up + 2) % 3, c = Math.cos(state.turn), s = Math.sin(state.turn);
      var px = new Float32Array(V), py = new Float32Array(V), pz = new Float32Array(V);
      for (var v = 0; v < V; v++) {
        var a = pos[v * 3 + h1] - mid[h1], b = pos[v * 3 + h2] - mid[h2], u = pos[v * 3 + up] - mid[up];
        px[v] = W / 2 + (c * a - s * b) * scale; pz[v] = s * a + c * b; py[v] = H / 2 - u * scale;
      }
      return {x: px, y: py, z: pz};
    }

    function draw(p, pos, err, scale) {
      var ctx = p.canvas.getContext("2d"), W = p.canvas.width, H = p.canvas.height;
      ctx.fillStyle = "#f6f6f4"; ctx.fillRect(0, 0, W, H);
      var at = project(pos, W, H, scale), px = at.x, py = at.y, pz = at.z;
      var order = new Array(F), depth = new Float32Array(F);
      for (var f = 0; f < F; f++) { order[f] = f; depth[f] = pz[faces[3 * f]] + pz[faces[3 * f + 1]] + pz[faces[3 * f + 2]]; }
      order.sort(function (i, j) { return depth[j] - depth[i]; });
      for (var n = 0; n < F; n++) {
        f = order[n];
        var i0 = faces[3 * f], i1 = faces[3 * f + 1], i2 = faces[3 * f + 2];
        var ax = px[i1] - px[i0], ay = py[i1] - py[i0], az = pz[i1] - pz[i0];
        var bx = px[i2] - px[i0], by = py[i2] - py[i0], bz = pz[i2] - pz[i0];
        var nx = ay * bz - az * by, ny = az * bx - ax * bz, nz = ax * by - ay * bx;
        var len = Math.sqrt(nx * nx + ny * ny + nz * nz) || 1;
        var light = 0.5 + 0.5 * Math.abs((0.3 * nx - 0.5 * ny - 0.8 * nz) / len);
        var rgb = err ? ramp((err[i0] + err[i1] + err[i2]) / 3) : [200, 204, 214];
        ctx.fillStyle = "rgb(" + (rgb[0] * light | 0) + "," + (rgb[1] * light | 0) + "," + (rgb[2] * light | 0) + ")";
        ctx.strokeStyle = ctx.fillStyle;  // the same colour round each edge hides the seams
        ctx.beginPath(); ctx.moveTo(px[i0], py[i0]); ctx.lineTo(px[i1], py[i1]); ctx.lineTo(px[i2], py[i2]); ctx.closePath(); ctx.fill(); ctx.stroke();
      }
    }

    // the ground truth's edges over a prediction, faint blue: where the two bodies part
    function overlay(p, pos, scale) {
      var ctx = p.canvas.getContext("2d"), at = project(pos, p.canvas.width, p.canvas.height, scale);
      var px = at.x, py = at.y;
      ctx.strokeStyle = "rgba(30, 70, 200, 0.18)"; ctx.lineWidth = 0.6; ctx.beginPath();
      for (var f = 0; f < F; f++) {
        var i0 = faces[3 * f], i1 = faces[3 * f + 1], i2 = faces[3 * f + 2];
        ctx.moveTo(px[i0], py[i0]); ctx.lineTo(px[i1], py[i1]); ctx.lineTo(px[i2], py[i2]); ctx.closePath();
      }
      ctx.stroke(); ctx.lineWidth = 1;
      p.canvas.setAttribute("data-overlay", "1");
    }

    function render() {
      var w = state.window, t = state.frame, future = t >= Tin;
      var gt = frameOf(truth, w, t, T);
      // the box's horizontal diagonal: what any turn can span across the canvas
      var across = Math.max(Math.sqrt(ext[(up + 1) % 3] * ext[(up + 1) % 3] + ext[(up + 2) % 3] * ext[(up + 2) % 3]), 1);
      var scale = 0.9 * Math.min(200 / across, 280 / Math.max(ext[up], 1));
      var over = $("overlay").checked;
      panels.forEach(function (p) {
        p.canvas.removeAttribute("data-overlay");
        if (p.still && future) {
          var held = frameOf(truth, w, Tin - 1, T), errs = new Float32Array(V), sum = 0;
          for (var q = 0; q < V; q++) {
            var ex = held[3 * q] - gt[3 * q], ey = held[3 * q + 1] - gt[3 * q + 1], ez = held[3 * q + 2] - gt[3 * q + 2];
            var d = Math.sqrt(ex * ex + ey * ey + ez * ez); sum += d; errs[q] = d / top;
          }
          draw(p, held, errs, scale);
          if (over) { overlay(p, gt, scale); }
          p.caption.textContent = p.name + ": mean vertex error " + (sum / V).toFixed(1) + " mm";
          return;
        }
        if (!p.model || !future) {
          draw(p, gt, null, scale);
          p.caption.textContent = p.name + (future ? "" : (p.model || p.still ? ": observed (input)" : ": observed"));
          return;
        }
        var pred = frameOf(preds[p.model], w, t - Tin, Tout), err = new Float32Array(V), total = 0;
        for (var v = 0; v < V; v++) {
          var dx = pred[3 * v] - gt[3 * v], dy = pred[3 * v + 1] - gt[3 * v + 1], dz = pred[3 * v + 2] - gt[3 * v + 2];
          var e = Math.sqrt(dx * dx + dy * dy + dz * dz); total += e; err[v] = e / top;
        }
        draw(p, pred, err, scale);
        if (over) { overlay(p, gt, scale); }
        p.caption.textContent = p.name + ": mean vertex error " + (total / V).toFixed(1) + " mm";
      });
      var note = $("ramp-note");
      note.textContent = " Prediction colour: its vertex error, from grey (0 mm) through orange to red (" + Math.round(top) + " mm or more: a twentieth of the largest body extent of these windows, the same scale for every window).";
      var bar = document.createElement("span"); bar.className = "ramp";
      bar.style.background = "linear-gradient(to right, " + RAMP.map(function (c) { return "rgb(" + c.join(",") + ")"; }).join(", ") + ")";
      note.insertBefore(bar, note.firstChild);
      slider.value = String(t);
      $("frame-label").textContent = "frame " + (t + 1) + " of " + T + (future ? " (+" + Math.round((t - Tin + 1) * 1000 / clips.fps) + " ms)" : " (observed)");
      viewer.setAttribute("data-frame", String(t));
    }

    // a frame starts one frame interval after the last one started, and never sooner than that
    // one took to draw after it ended: where drawing takes over half an interval, playback
    // slows down and half the page's time stays free for the reader's clicks, instead of frames
    // queueing ahead of them (data-interval-ms is the interval asked for)
    var timer = null;
    function play(on) {
      state.playing = on; $("play").textContent = on ? "pause" : "play";
      if (timer) { clearTimeout(timer); timer = null; }
      var every = 1000 / (clips.fps * +$("speed").value);
      viewer.setAttribute("data-interval-ms", on ? String(every) : "");
      function next() {
        var began = performance.now();
        try { state.frame = (state.frame + 1) % T; render(); } finally {
          var spent = performance.now() - began;
          timer = setTimeout(next, Math.max(every - spent, spent));
        }
      }
      if (on) { timer = setTimeout(next, every); }
    }
    $("play").addEventListener("click", function () { play(!state.playing); });
    slider.addEventListener("input", function () { play(false); state.frame = +slider.value; render(); });
    $("speed").addEventListener("change", function () { if (state.playing) { play(true); } });
    $("overlay").addEventListener("change", render);
    $("turn").addEventListener("input", function () { state.turn = +$("turn").value * Math.PI / 180; render(); });
    $("clip-window").addEventListener("change", function () { state.window = +$("clip-window").value; measure(state.window); render(); });
    render();
  }
  return {start: start};
})();
