// compd's status page: reads /status.json, /page.json and /history.json and draws them.
// Read-only: it only GETs. Every name comes from a config or a model file, so it is set as
// text (textContent), never parsed as markup.
// A page that shows frozen values under a green badge lies: when compd stops answering, the
// header turns "dead" (no answer for N s) at the first failed refresh, within two refresh
// periods; when it answers but its ticks stop, "stale" (no tick for N s).
"use strict";

const REFRESH_MS = 2000;
const WATCH_MS = 1000; // how often the header's "no answer for N s" is counted on
const HISTORY_EVERY = 5; // refreshes between two fetches of the hour's history
const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#e377c2"];
const SVG = "http://www.w3.org/2000/svg";

function el(tag, text, cls) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = String(text);
  if (cls) node.className = cls;
  return node;
}

function num(value, digits) {
  return value === null || value === undefined ? "-" : Number(value).toFixed(digits);
}

function utc(unixS) {
  return new Date(unixS * 1000).toISOString().replace("T", " ").replace(/\.\d+Z$/, "Z");
}

function fillTable(id, rows) {
  const body = document.querySelector(`#${id} tbody`);
  body.replaceChildren(...rows);
}

function row(cells, cls) {
  const tr = el("tr", null, cls);
  for (const [text, numeric] of cells) tr.append(el("td", text, numeric ? "num" : undefined));
  return tr;
}

function fillList(id, pairs) {
  const list = document.getElementById(id);
  const items = [];
  for (const [key, value] of pairs) items.push(el("dt", key), el("dd", value === null || value === undefined ? "-" : value));
  list.replaceChildren(...items);
}

// What the header says: alive (the status level), stale (answers, no ticks) or dead (no answer).
const health = { answeredMs: performance.now(), failing: false, tickAgeS: null, periodS: 1, level: null, machine: null, notConnected: [] };

function showHealth() {
  const level = document.getElementById("level");
  const silentS = Math.round((performance.now() - health.answeredMs) / 1000);
  let state, text;
  if (health.failing) {
    state = "dead";
    text = `no answer for ${silentS} s`;
  } else if (health.tickAgeS !== null && health.tickAgeS > 2 * health.periodS + REFRESH_MS / 1000) {
    state = "stale";
    text = `stale: no tick for ${Math.round(health.tickAgeS + silentS)} s`;
  } else {
    state = "alive";
    text = health.level || "starting";
    // A driver that never answered since start: nothing reaches the machine, whatever the level says.
    if (health.notConnected.length) text += `: ${health.notConnected.join(", ")} not connected`;
  }
  level.textContent = text;
  level.className = `level ${state === "alive" ? health.level || "" : state}`;
  document.body.dataset.state = state;
  const where = health.machine ? `${health.machine} ` : "";
  const mark = state === "alive" ? "" : "\u2716 ";
  document.title = `${mark}${where}${state === "alive" ? text : state} - compd`;
}

function showStatus(status, page) {
  // A data logger (no outputs) runs no model: status.model and page.model are null.
  document.getElementById("machine").textContent = page.machine_id || "";
  document.getElementById("model-name").textContent = status.model ? status.model.name : "recording (a data logger, no model)";
  document.getElementById("last-tick").textContent = status.last_tick || "not yet";
  health.level = page.status.level;
  health.notConnected = Object.keys(status.drivers).filter((name) => status.drivers[name] === "not connected");
  health.machine = page.machine_id;
  health.periodS = page.period_s;
  health.tickAgeS = status.last_tick_age_s;
  document.getElementById("flags").replaceChildren(...page.status.flags.map((f) => el("span", f)));
  // Beside a level that may read ok: what compd cannot assure (an input nothing verifies, ...).
  const notAssured = document.getElementById("not-assured");
  notAssured.textContent = page.not_assured.join("; ");
  notAssured.hidden = page.not_assured.length === 0;

  fillTable("offsets", Object.keys(status.offsets_um).map((axis) => row([
    [axis], [num(status.offsets_um[axis], 2), true],
    [num(status.offsets_held_um[axis], 2), true], [num(status.targets_um[axis], 2), true],
  ])));
  fillTable("inputs", Object.entries(status.inputs).map(([name, input]) => row([
    [name], [num(input.value, 2), true], [page.units[name] || ""], [input.health], [input.reason || ""],
  ], input.health)));

  const word = page.status.word;
  fillList("status", [
    ["status word", word === null ? null : `${word} (0x${word.toString(16).padStart(8, "0")})`],
    ["level", page.status.level],
    ["flags", page.status.flags.join(", ") || "none"],
    ["heartbeat", status.heartbeat],
    ["started", status.started],
    ["resumed state", status.resumed ? "yes" : "no"],
    ["gain schedule", status.gain_schedule === null ? "none" : JSON.stringify(status.gain_schedule)],
    ["config", page.config],
  ]);
  fillList("drivers", Object.entries(status.drivers));
  fillList("counters", Object.entries(status.counters).map(([k, v]) => [k.replaceAll("_", " "), v]));

  const faults = page.faults.map((f) => row([[utc(f.at_unix_s)], [f.kind], [f.source], [f.message]]));
  fillTable("faults", faults);
  document.getElementById("no-faults").hidden = faults.length > 0;

  const m = page.model;
  if (!m) {
    fillList("model", [["model", "none: a data logger, recording its signals"]]);
    return;
  }
  const fits = Object.entries(m.fit_percent).map(([out, pct]) => `${out} ${num(pct, 1)} %`).join(", ");
  fillList("model", [
    ["name", m.name],
    ["sha256", m.sha256],
    ["file", m.path],
    ["description", m.description || null],
    ["loaded", status.model.loaded],
    ["fit (calibration)", fits || null],
    ["expected on new data", m.held_out_fit_percent === null ? m.held_out_note || null : `${num(m.held_out_fit_percent, 1)} %`],
    ["method", m.method],
    ["created", m.created],
    ["data", m.data],
    ["command", m.command],
    ["compd version", m.compd_version],
    ["updates / extensions", `${m.updates} / ${m.extensions}`],
    ["initialised", status.model.initialised],
    ["pending", status.model.pending],
    ["blending from", status.model.blending_from],
    ["fault", status.model.fault],
  ]);
}

function svg(tag, attrs, text) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, String(v));
  if (text !== undefined) node.textContent = text;
  return node;
}

// A line per series over time: plain SVG, y range from the data, a zero line when it is in range;
// a vertical mark at each fault's start (red), model load (blue) and probe (green), its reason as a tooltip.
function drawChart(id, legendId, t, series, marks) {
  const chart = document.getElementById(id);
  const W = 640, H = 200, L = 52, R = 8, T = 8, B = 22;
  const names = Object.keys(series);
  const all = names.flatMap((n) => series[n]).filter((v) => v !== null);
  const nodes = [];
  const legend = [];
  if (t.length >= 2 && all.length) {
    let lo = Math.min(...all), hi = Math.max(...all);
    if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
    const pad = (hi - lo) * 0.05; lo -= pad; hi += pad;
    const t0 = t[0], t1 = t[t.length - 1];
    const x = (ts) => L + ((ts - t0) / Math.max(t1 - t0, 1e-9)) * (W - L - R);
    const y = (v) => T + (1 - (v - lo) / (hi - lo)) * (H - T - B);
    for (const v of [lo + pad, (lo + hi) / 2, hi - pad]) {
      nodes.push(svg("line", { x1: L, x2: W - R, y1: y(v), y2: y(v), class: "grid" }));
      nodes.push(svg("text", { x: L - 4, y: y(v) + 4, "text-anchor": "end" }, v.toFixed(2)));
    }
    for (const m of marks) {
      if (m.at_unix_s < t0 || m.at_unix_s > t1) continue;
      const cls = m.kind === "model_load" ? "load" : m.kind === "probe" ? "probe" : "fault";
      const line = svg("line", { x1: x(m.at_unix_s), x2: x(m.at_unix_s), y1: T, y2: H - B, class: `mark ${cls}`, "data-kind": m.kind });
      line.append(svg("title", {}, `${utc(m.at_unix_s)} ${m.kind} ${m.source}: ${m.message}`));
      nodes.push(line);
    }
    nodes.push(svg("text", { x: L, y: H - 6 }, utc(t0).slice(11)));
    nodes.push(svg("text", { x: W - R, y: H - 6, "text-anchor": "end" }, utc(t1).slice(11)));
    names.forEach((name, i) => {
      const colour = COLOURS[i % COLOURS.length];
      // A gap (null) splits the line, so a missing value is not drawn as a straight jump.
      let points = [];
      const flush = () => {
        if (points.length) nodes.push(svg("polyline", { points: points.join(" "), stroke: colour, "data-series": name }));
        points = [];
      };
      series[name].forEach((v, k) => {
        if (v === null) flush(); else points.push(`${x(t[k]).toFixed(1)},${y(v).toFixed(1)}`);
      });
      flush();
      const key = el("span", name);
      const swatch = document.createElement("i");
      swatch.style.background = colour;
      key.prepend(swatch);
      legend.push(key);
    });
  } else {
    nodes.push(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, "no ticks yet"));
  }
  chart.replaceChildren(...nodes);
  document.getElementById(legendId).replaceChildren(...legend);
}

let marks = []; // the faults, model loads and probes page.json last listed

// Per probed axis: due, the last probe and its innovation, the shift's RMS (a config without probes: hidden).
function showProbes(probes) {
  document.getElementById("probes-section").hidden = !probes;
  if (!probes) return;
  fillTable("probes", Object.entries(probes).map(([axis, p]) => row([
    [axis], [p.due ? "yes" : "no"], [p.last ? p.last.result : "none yet"],
    [p.last ? num(p.last.innovation_um, 2) : "-", true],
    [p.last_taken_age_s === null ? "-" : `${Math.round(p.last_taken_age_s / 60)} min`, true],
    [num(p.shift_rms_um, 2), true], [p.shift_probes, true], [num(p.adjustment_um, 2), true],
  ], p.disagrees ? "faulted" : undefined)));
}

function showHistory(history) {
  drawChart("chart-offsets", "legend-offsets", history.t_unix_s, history.offsets_um, marks);
  const temps = {};
  for (const [name, values] of Object.entries(history.inputs)) {
    if (history.units[name] === "degC") temps[name] = values;
  }
  drawChart("chart-inputs", "legend-inputs", history.t_unix_s, temps, marks);
}

async function getJson(path) {
  // A stopped (SIGSTOP) or unreachable compd never answers: give up at the next refresh.
  const response = await fetch(path, { cache: "no-store", signal: AbortSignal.timeout(REFRESH_MS) });
  if (!response.ok) throw new Error(`${path}: HTTP ${response.status}`);
  return response.json();
}

let refreshes = 0;
async function refresh() {
  const error = document.getElementById("error");
  try {
    const [status, page] = await Promise.all([getJson("status.json"), getJson("page.json")]);
    health.answeredMs = performance.now();
    health.failing = false;
    showStatus(status, page);
    showProbes(page.probes);
    marks = [...page.faults, ...page.model_loads, ...page.probe_marks];
    if (refreshes % HISTORY_EVERY === 0) showHistory(await getJson("history.json?points=720"));
    document.body.dataset.loaded = String(refreshes + 1);
    error.hidden = true;
  } catch (exc) {
    health.failing = true;
    error.textContent = `compd does not answer: ${exc.message}`;
    error.hidden = false;
  }
  showHealth();
  refreshes += 1;
  setTimeout(refresh, REFRESH_MS);
}

document.addEventListener("DOMContentLoaded", () => {
  refresh();
  setInterval(showHealth, WATCH_MS);
});
