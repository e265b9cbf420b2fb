// Landing page: polls /api/cells every 500 ms and redraws one card per cell (no reload).
"use strict";

const POLL_MS = 500;
const MODES = ["intended", "failsafe", "fault", "rest"];
const STALE_S = 1.0; // a mode older than this is not shown as live
const VIEWERS = {}; // cell -> its 3D view (serve --cells N), from /api/links

function fmt(x, digits, unit) {
  if (x === null || x === undefined || !Number.isFinite(x)) return "–";
  return x.toFixed(digits) + (unit ? " " + unit : "");
}

function row(dl, label, value) {
  const dt = document.createElement("dt");
  dt.textContent = label;
  const dd = document.createElement("dd");
  dd.textContent = value;
  dd.dataset.field = label;
  dl.append(dt, dd);
}

function ages(obj) {
  const parts = Object.entries(obj || {}).map(([id, a]) => id + " " + fmt(a * 1000, 0, "ms"));
  return parts.length ? parts.join(", ") : "–";
}

// "superseded": a newer message of the same key replaced it before the cycle read it, which is
// normal operation (the newest is used), not a loss: shown apart, never as a drop
function dropped(obj) {
  const entries = Object.entries(obj || {}).filter(([r, n]) => n > 0 && r !== "superseded");
  const total = entries.reduce((s, [, n]) => s + n, 0);
  return total ? total + " (" + entries.map(([r, n]) => r + " " + n).join(", ") + ")" : "none";
}

function card(c) {
  const stale = c.online && (c.verdict_age_s === null || c.verdict_age_s > STALE_S);
  const mode = c.online && !stale && MODES.includes(c.mode) ? c.mode : "rest";
  const el = document.createElement("article");
  el.className = "cell mode-" + mode + (c.online || c.starting ? "" : " offline");
  el.dataset.cell = c.cell;
  el.dataset.mode = !c.online ? "offline" : stale ? "stale" : c.mode || "";
  const h = document.createElement("h2");
  h.textContent = c.cell;
  const badge = document.createElement("span");
  badge.className = "badge";
  const starting = !!c.starting;
  if (starting) el.dataset.mode = "starting";
  badge.textContent = starting ? "starting" : !c.online ? "offline"
    : stale ? "no recent verdict" : c.mode;
  const safety = document.createElement("span");
  safety.className = "tag";
  safety.title = "safety mode (from the latest verdict)";
  safety.textContent = (c.safety_mode || "–").toUpperCase();
  el.dataset.safetyMode = c.safety_mode || "";
  h.append(safety, badge);
  const dl = document.createElement("dl");
  row(dl, "scenario", c.scenario || "–");
  row(dl, "safety mode", c.safety_mode || "–");
  row(dl, "min distance", fmt(c.min_distance_m, 3, "m"));
  row(dl, "cycle p50 / p99", fmt(c.cycle_time_p50_us, 0) + " / " + fmt(c.cycle_time_p99_us, 0, "µs"));
  row(dl, "skeleton age", ages(c.skeleton_age_s));
  row(dl, "dropped", dropped(c.dropped));
  if (c.faults && c.faults.length) row(dl, "faults", c.faults.join("; "));
  row(dl, "state", (c.state || "–") + (c.detail ? ": " + c.detail : ""));
  row(dl, "last verdict", fmt(c.verdict_age_s, 1, "s ago"));
  row(dl, "last status", fmt(c.status_age_s, 1, "s ago"));
  // the configuration checksum an evidence report prints (sara-app report)
  row(dl, "configuration", c.config_sha256 || "–");
  dl.lastElementChild.className = "checksum";
  const more = document.createElement("p");
  more.className = "more";
  const viewer = VIEWERS[c.cell];
  if (viewer) {  // serve --cells N: each cell has its own 3D view
    const a = document.createElement("a");
    a.href = viewer;
    a.textContent = "3D view";
    more.append(a);
  }
  for (const [text, path] of [["thresholds", "/thresholds"], ["threshold audit", "/thresholds/audit"]]) {
    const a = document.createElement("a");
    a.href = "/api/cells/" + encodeURIComponent(c.cell) + path;
    a.textContent = text;
    more.append(a);
  }
  // the verdict in words (the API's sentence: sara_app/bus/verdict_words.py), coloured by state
  const verdict = document.createElement("p");
  verdict.className = "verdict";
  verdict.dataset.state = c.verdict_state || "offline";
  verdict.style.borderLeftColor = c.verdict_colour || "#6b7280";
  verdict.textContent = starting ? "Starting: " + (c.detail || "building the cell")
    : c.verdict_text || "No verdict yet";
  el.append(h, verdict, dl, more);
  return el;
}

async function poll() {
  const conn = document.getElementById("connection");
  try {
    const r = await fetch("/api/cells", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    const cells = await r.json();
    document.getElementById("cells").replaceChildren(...cells.map(card));
    document.getElementById("empty").hidden = cells.length > 0;
    conn.textContent = "live · " + new Date().toLocaleTimeString();
    conn.classList.remove("lost");
  } catch (e) {
    conn.textContent = "service unreachable (" + e.message + "), retrying…";
    conn.classList.add("lost");
  } finally {
    setTimeout(poll, POLL_MS);
  }
}

async function links() {
  try {
    const r = await fetch("/api/links", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    const l = await r.json();
    Object.assign(VIEWERS, l.viewers || {});
    if (l.viewer) {
      const a = document.getElementById("viewer-link");
      a.href = l.viewer;
      a.hidden = false;
    }
  } catch (e) {
    /* the page works without the links meanwhile; asked again until they come */
    setTimeout(links, POLL_MS);
  }
}

links();
poll();
