// pmalab live view: Server-Sent Events from the local server -> uPlot charts.
// Units: t in s from the run's start, x = contraction in mm (positive = shorter),
// f = tension in N, pm / pc / cmd = muscle / cylinder pressure / cylinder command in MPa.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const COLORS = { cur: "#ea580c", prev: "rgba(37,99,235,0.55)", old: "rgba(37,99,235,0.16)",
                   force: "#ea580c", pos: "#7c3aed", pm: "#16a34a", pc: "#2563eb", cmd: "#9ca3af" };
  const MAX_OLD_POINTS = 1000;  // uPlot thins a path by pixel column above ~4 points/px
  const stats = { events: 0, points: 0, draws: 0, fps: 0, loopPoints: 0, run: null,
                  status: null, ended: false };
  window.pmalabStats = stats;

  let info = null;          // the shown run's timeline (from the "run" event)
  let D = empty();          // its decimated samples
  let dirty = false;
  let source = null;
  let selected = "";        // "" = follow the current run, else a run index

  function empty() { return { t: [], x: [], f: [], pm: [], pc: [], cmd: [] }; }

  // ------------------------------------------------------------------ charts
  const linear = uPlot.paths.linear();
  function facet(label, stroke, width) {
    return { label, stroke, width, paths: linear, points: { show: false },
             facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }] };
  }
  function size(el, h) { return { width: Math.max(300, el.clientWidth || 500), height: h }; }

  const loopEl = $("loop");
  const loop = new uPlot({
    mode: 2, ...size(loopEl, 460), legend: { live: false }, cursor: { show: false },
    scales: { x: { time: false }, y: {} },
    axes: [{ label: "contraction x (mm)" }, { label: "tension F (N)" }],
    // integer line widths: a software-rasterised canvas (no GPU) strokes them far faster
    series: [{}, facet("older cycles", COLORS.old, 1), facet("previous cycle", COLORS.prev, 1),
             facet("current cycle", COLORS.cur, 2)],
  }, [null, [[], []], [[], []], [[], []]], loopEl);

  function timeChart(el, yLabel, series, h) {
    return new uPlot({
      ...size(el, h), cursor: { sync: { key: "pmalab-t" } }, legend: { live: false },
      scales: { x: { time: false } },
      axes: [{ label: "t (s)" }, { label: yLabel }],
      series: [{ label: "t (s)" }, ...series.map(([label, stroke, dash]) =>
        ({ label, stroke, width: 1, dash, points: { show: false } }))],
    }, [[], ...series.map(() => [])], el);
  }
  const tf = timeChart($("tf"), "F (N)", [["tension F (N)", COLORS.force]], 150);
  const tx = timeChart($("tx"), "x (mm)", [["contraction x (mm)", COLORS.pos]], 150);
  const tp = timeChart($("tp"), "MPa", [["muscle (MPa)", COLORS.pm], ["cylinder (MPa)", COLORS.pc],
                                        ["command (MPa)", COLORS.cmd, [4, 4]]], 170);

  window.addEventListener("resize", () => {
    loop.setSize(size(loopEl, 460));
    for (const [u, id, h] of [[tf, "tf", 150], [tx, "tx", 150], [tp, "tp", 170]]) u.setSize(size($(id), h));
  });

  // ------------------------------------------------------------------ drawing
  function lowerBound(a, v) {  // first index with a[i] >= v (a ascending)
    let lo = 0, hi = a.length;
    while (lo < hi) { const m = (lo + hi) >> 1; if (a[m] < v) lo = m + 1; else hi = m; }
    return lo;
  }
  function thin(a, i0, i1, max) {
    const step = Math.max(1, Math.ceil((i1 - i0) / max)), out = [];
    for (let i = i0; i < i1; i += step) out.push(a[i]);
    if (i1 > i0 && (i1 - 1 - i0) % step) out.push(a[i1 - 1]);
    return out;
  }
  function cycleOf(t) {  // -1 during settle + ramp in, 0..cycles-1 steady, cycles: ramp out
    const f = info && info.frequency_Hz, s = info ? info.steady_start_s : 0;
    if (!f) return 0;
    return Math.min(Math.max(Math.floor((t - s) * f), -1), Math.ceil(info.cycles || 0));
  }
  function cycleStart(c) {
    return c <= -1 ? -Infinity : info.steady_start_s + c / info.frequency_Hz;
  }

  function drawLoop() {
    const n = D.t.length;
    let iCur = 0, iPrev = 0;
    if (n && info && info.frequency_Hz) {
      const c = cycleOf(D.t[n - 1]);
      iCur = lowerBound(D.t, cycleStart(c));
      iPrev = lowerBound(D.t, cycleStart(c - 1));
    }
    // neighbouring pieces share a point so the trace is unbroken
    const a = Math.max(0, iPrev - 0), b = Math.max(0, iCur - 1);
    loop.setData([null,
      [thin(D.x, 0, Math.min(n, iPrev + 1), MAX_OLD_POINTS), thin(D.f, 0, Math.min(n, iPrev + 1), MAX_OLD_POINTS)],
      [D.x.slice(a, iCur + 1), D.f.slice(a, iCur + 1)],
      [D.x.slice(b), D.f.slice(b)]]);
    stats.loopPoints = n;
  }

  function drawTime() {
    const n = D.t.length, w = Number($("window").value);
    const charts = [[tf, [D.t, D.f]], [tx, [D.t, D.x]], [tp, [D.t, D.pm, D.pc, D.cmd]]];
    for (const [u, data] of charts) {
      if (!w || !n) { u.setData(data); continue; }
      const tmax = D.t[n - 1];
      u.batch(() => { u.setData(data, false); u.setScale("x", { min: Math.max(tmax - w, D.t[0]), max: Math.max(tmax, D.t[0] + 1e-3) }); });
    }
  }

  let drawsThisSecond = 0;
  setInterval(() => { stats.fps = drawsThisSecond; drawsThisSecond = 0; $("fps").textContent = stats.fps + " /s"; }, 1000);
  function frame() {
    if (dirty) {
      dirty = false;
      const t0 = performance.now();
      drawLoop();
      const t1 = performance.now();
      drawTime();
      const t2 = performance.now();
      stats.loopMs = 0.9 * (stats.loopMs || 0) + 0.1 * (t1 - t0);  // moving averages, ms
      stats.timeMs = 0.9 * (stats.timeMs || 0) + 0.1 * (t2 - t1);
      stats.draws++; drawsThisSecond++;
      if (D.t.length) {  // redraws with points on the page: the update rate a user sees
        stats.pointDraws = (stats.pointDraws || 0) + 1;
        stats.lastDrawAt = t2;
        if (stats.firstDrawAt === undefined) stats.firstDrawAt = t0;
      }
    }
    requestAnimationFrame(frame);
  }
  requestAnimationFrame(frame);

  // ------------------------------------------------------------------ header and tables
  function fmt(v, d) { return (v === undefined || v === null) ? "—" : Number(v).toFixed(d); }
  const DIGITS = { N: 1, mm: 2, MPa: 3 };

  function showRun(r) {
    $("run-name").textContent = r.name;
    $("run-pos").textContent = `run ${r.index + 1}/${r.n_runs} · ${fmt(r.muscle_pressure_MPa, 3)} MPa · ` +
      `${r.waveform} ${r.frequency_Hz} Hz × ${r.cycles}`;
    addRunOption(r.index, r.name);
  }
  function addRunOption(index, name) {
    const sel = $("run-select");
    if ([...sel.options].some((o) => o.value === String(index))) return;
    const o = document.createElement("option");
    o.value = String(index); o.textContent = `${index + 1}: ${name}`;
    sel.appendChild(o);
  }

  function showStatus(s) {
    stats.status = s;
    const safety = s.safety || { state: "waiting", text: "" };
    const badge = $("safety");
    badge.className = "badge " + safety.state;
    badge.textContent = safety.text;
    if (s.message) $("message").textContent = s.message;
    if (s.progress_run !== undefined) {
      $("prog-run").style.width = (100 * s.progress_run).toFixed(1) + "%";
      $("prog-run-text").textContent = `run ${fmt(s.t, 1)} / ${fmt(s.duration_s, 1)} s`;
      $("prog-proto").style.width = (100 * s.progress_protocol).toFixed(1) + "%";
      $("prog-proto-text").textContent = `protocol ${(100 * s.progress_protocol).toFixed(0)} % (run ${s.index + 1}/${s.n_runs})`;
    }
    $("n-samples").textContent = s.samples ?? 0;
    $("n-late").textContent = s.late ?? 0;
    $("n-missed").textContent = s.missed ?? 0;
    $("n-dropped").textContent = s.dropped ?? 0;
    const body = $("margins").tBodies[0];
    body.innerHTML = "";
    for (const m of s.margins || []) {
      const d = DIGITS[m.unit] ?? 2, tr = document.createElement("tr");
      const cls = m.used > 0.95 ? "high" : m.used > 0.8 ? "warn" : "";
      tr.innerHTML = `<td>${m.channel.replace("_", " ")}</td><td>${fmt(m.reading, d)} ${m.unit}</td>` +
        `<td>${m.trip} ${m.unit}</td><td>${fmt(m.margin, d)}</td><td>${fmt(m.lowest, d)}</td>` +
        `<td><div class="used ${cls}"><div style="width:${(100 * m.used).toFixed(0)}%"></div></div></td>`;
      body.appendChild(tr);
    }
    if (safety.state === "aborted" || safety.state === "completed" || safety.state === "stopping") $("stop").disabled = true;
  }

  // ------------------------------------------------------------------ stream
  let stopAllowed = false;
  function connect() {
    if (source) source.close();
    source = new EventSource("/events" + (selected === "" ? "" : "?run=" + selected));
    $("conn").textContent = "connecting";
    source.addEventListener("open", () => { $("conn").textContent = "connected"; });
    source.addEventListener("error", () => {
      $("conn").textContent = stats.ended ? "closed (source finished)" : "lost — retrying";
    });
    source.addEventListener("hello", (e) => {
      const h = JSON.parse(e.data);
      $("mode").textContent = h.mode === "view" ? "view" : "live";
      $("source").textContent = h.file || "";
      document.title = `pmalab ${h.mode} — ${h.file || ""}`;
      for (const r of h.runs || []) addRunOption(r.index, r.name);
      stopAllowed = !!h.stop_allowed;
      const stop = $("stop");
      stop.disabled = !stopAllowed;
      stop.title = stopAllowed ? "vent the regulator and close the run, keeping its samples (as Ctrl-C)"
        : h.mode === "view" ? "viewing a file: nothing to stop" : "stop is accepted only from 127.0.0.1";
      if (h.mode === "view") $("safety").className = "badge viewing";
    });
    source.addEventListener("run", (e) => {
      info = JSON.parse(e.data);
      D = empty(); dirty = true;
      stats.run = info.name; stats.points = 0;
      showRun(info);
    });
    source.addEventListener("points", (e) => {
      const p = JSON.parse(e.data);
      if (!info || p.run !== info.index) return;
      for (const k of ["t", "x", "f", "pm", "pc", "cmd"]) { const a = D[k]; for (const v of p[k]) a.push(v); }
      stats.events++; stats.points += p.t.length; dirty = true;
    });
    source.addEventListener("status", (e) => showStatus(JSON.parse(e.data)));
    source.addEventListener("end", (e) => {
      stats.ended = true;
      const m = JSON.parse(e.data).message;
      $("conn").textContent = "finished";
      if (m) $("message").textContent = m;
      $("stop").disabled = true;
      source.close();
    });
  }

  $("run-select").addEventListener("change", (e) => { selected = e.target.value; stats.ended = false; connect(); });
  $("window").addEventListener("change", () => { dirty = true; });
  $("stop").addEventListener("click", async () => {
    const stop = $("stop");
    stop.disabled = true;
    try {
      const r = await fetch("/stop", { method: "POST", headers: { "X-Pmalab-Stop": "1" } });
      const j = await r.json();
      $("stop-reply").textContent = j.message;
      if (!r.ok) stop.disabled = !stopAllowed;
    } catch (err) {
      $("stop-reply").textContent = "stop request failed: " + err + " — use Ctrl-C in the terminal";
      stop.disabled = !stopAllowed;
    }
  });
  connect();
})();
