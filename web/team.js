// Team missions and the center's safety functions on the dashboard: separation warnings, each team
// mission's vehicles and legs, and the shore's proposals to restructure a team (an operator confirms or
// dismisses them; with restructure_auto they are applied at once). Reads the API every few seconds with
// the dashboard's token; kept apart from app.js, which it does not touch.
"use strict";

(() => {
  const REFRESH_MS = 3000;
  const el = (tag, text = "", cls = "") => {
    const node = document.createElement(tag);
    if (text) node.textContent = text;
    if (cls) node.className = cls;
    return node;
  };

  function token() { return localStorage.getItem("tacit-token") || ""; }

  async function call(path, method = "GET") {
    const response = await fetch(`/api/v1${path}`, { method, headers: { Authorization: `Bearer ${token()}` } });
    const body = await response.json().catch(() => ({}));
    if (!response.ok) throw new Error(body.detail || `HTTP ${response.status}`);
    return body;
  }

  function card() {
    const section = el("section", "", "card wide");
    section.id = "team-card";
    section.append(el("h2", "Team missions and safety"));
    for (const [id, title] of [["team-warnings", "Separation warnings"], ["team-proposals", "Proposals"], ["team-list", "Team missions"]]) {
      section.append(el("h3", title));
      const box = el("div");
      box.id = id;
      section.append(box);
    }
    const result = el("p", "", "note");
    result.id = "team-result";
    result.setAttribute("role", "status");
    section.append(result);
    document.getElementById("main").append(section);
    return section;
  }

  function warnings(safety) {
    const box = document.getElementById("team-warnings");
    box.replaceChildren();
    if (!safety.warnings.length) {
      box.append(el("p", `none (separation ${safety.separation_m} m)`, "note"));
      return;
    }
    for (const w of safety.warnings) {
      box.append(el("p", `${w.vehicles.join(" and ")}: ${w.distance_m} m apart, within ${w.limit_m} m `
        + `(separation ${w.separation_m} m + uncertainty ${w.uncertainty_m} m)`, "error"));
    }
  }

  function decide(id, action) {
    call(`/proposals/${id}/${action}`, "POST")
      .then((p) => { document.getElementById("team-result").textContent = `proposal ${p.id}: ${p.status} ${p.detail}`; })
      .catch((e) => { document.getElementById("team-result").textContent = `proposal ${id}: ${e.message}`; })
      .finally(refresh);
  }

  function proposals(list, canWrite) {
    const box = document.getElementById("team-proposals");
    box.replaceChildren();
    if (!list.length) box.append(el("p", "none", "note"));
    for (const p of list.slice(0, 5)) {
      const work = p.work.map((w) => `${w.name} to (${w.target[0]} N, ${w.target[1]} E, ${w.target[2]} m)`).join("; ");
      const row = el("p", `#${p.id} team ${p.team_id}: ${p.finder} found a time-sensitive anomaly at `
        + `(${p.anomaly[0]} N, ${p.anomaly[1]} E): ${work} [${p.status}${p.decided_by ? ` by ${p.decided_by}` : ""}] `);
      row.className = "team-proposal";
      if (p.status === "proposed" && canWrite) {
        for (const action of ["confirm", "dismiss"]) {
          const button = el("button", action, "write");
          button.type = "button";
          button.addEventListener("click", () => decide(p.id, action));
          row.append(button);
        }
      }
      box.append(row);
    }
  }

  function teams(list) {
    const box = document.getElementById("team-list");
    box.replaceChildren();
    if (!list.length) box.append(el("p", "none (POST /api/v1/teams)", "note"));
    for (const t of list.slice(0, 3)) {
      box.append(el("p", `${t.name} (#${t.id}): ${t.status}, ${t.link.legs} legs, `
        + `about ${t.link.channel_s_per_leg} s of the channel each`));
      const table = el("table");
      for (const m of t.members) {
        const tr = el("tr");
        const leg = `leg ${Math.min(m.next + 1, m.waypoints.length)} of ${m.waypoints.length}`;
        for (const text of [m.name, m.state, leg, m.reason]) tr.append(el("td", text));
        table.append(tr);
      }
      box.append(table);
    }
  }

  async function refresh() {
    if (!token() || document.getElementById("main").hidden) return;
    if (!document.getElementById("team-card")) card();
    try {
      const [who, safety, props, list] = await Promise.all(
        ["/whoami", "/safety", "/proposals", "/teams"].map((path) => call(path)));
      warnings(safety);
      proposals(props, who.role === "write");
      teams(list);
    } catch (e) {
      document.getElementById("team-result").textContent = `team missions: ${e.message}`;
    }
  }

  setInterval(refresh, REFRESH_MS);
  window.addEventListener("load", refresh);
})();
