// Team missions and the center's safety functions on the dashboard: separation warnings, the shore's
// proposals to restructure a team (an operator confirms or dismisses them; with restructure_auto they are
// applied at once), a form that creates a team mission (an area and the vehicles), and each team with its
// vehicles, legs and buttons to start, abort or delete it; a refusal's reason shows beside the button that
// was pressed. Reads the API every few seconds with the dashboard's token; kept apart from app.js, which it
// does not touch.
"use strict";

(() => {
  const REFRESH_MS = 3000;
  // a survey north of the demo fleet's squares (docs/missions.md): a start that works there as it is
  const EXAMPLE = { name: "river survey", south: 25, north: 65, west: -5, east: 85, spacing: 6, depth: 2 };
  const ACTIONS = { created: ["start", "delete"], refused: ["start", "delete"], started: ["abort"], aborted: ["delete"], finished: ["delete"] };
  const outcome = new Map(); // team id -> what its last button did (kept across refreshes)
  let canWrite = false;

  const el = (tag, text = "", cls = "") => {
    const node = document.createElement(tag);
    if (text) node.textContent = text;
    if (cls) node.className = cls;
    return node;
  };

  function token() { return localStorage.getItem("tacit-token") || ""; }

  async function call(path, method = "GET", body = undefined) {
    const headers = { Authorization: `Bearer ${token()}` };
    if (body !== undefined) headers["Content-Type"] = "application/json";
    const response = await fetch(`/api/v1${path}`, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
    if (response.status === 204) return {};
    const answer = await response.json().catch(() => ({}));
    if (!response.ok) throw new Error(typeof answer.detail === "string" ? answer.detail : `HTTP ${response.status}`);
    return answer;
  }

  function card() {
    const section = el("section", "", "card wide");
    section.id = "team-card";
    section.append(el("h2", "Team missions and safety"));
    for (const [id, title] of [["team-warnings", "Separation warnings"], ["team-proposals", "Proposals"], ["team-new", "New team mission"], ["team-list", "Team missions"]]) {
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
    form(document.getElementById("team-new"));
    return section;
  }

  function number(name, label, value, hint) {
    const wrap = el("label", label);
    wrap.title = hint;
    const input = el("input");
    Object.assign(input, { type: "number", step: "any", name, value: String(value), required: true });
    input.id = `team-${name}`;
    wrap.append(input);
    return wrap;
  }

  function form(box) {
    const f = el("form", "", "team-form write-only");
    f.id = "team-form";
    f.noValidate = true;
    const name = el("label", "Name");
    const nameInput = el("input");
    Object.assign(nameInput, { name: "name", value: EXAMPLE.name, required: true, maxLength: 128 });
    nameInput.id = "team-name";
    name.append(nameInput);
    f.append(name);
    const area = el("fieldset");
    area.append(el("legend", "Area (m north and east of the fleet's origin)"));
    for (const [key, label] of [["south", "South"], ["north", "North"], ["west", "West"], ["east", "East"]]) {
      area.append(number(key, label, EXAMPLE[key], `the area's ${key} edge`));
    }
    f.append(area);
    f.append(number("spacing", "Lane spacing (m)", EXAMPLE.spacing, "metres between lanes; neighbouring vehicles' lanes must be at least the separation apart"));
    f.append(number("depth", "Depth (m)", EXAMPLE.depth, "the survey's depth"));
    const vehicles = el("fieldset");
    vehicles.id = "team-vehicles";
    vehicles.append(el("legend", "Vehicles (west to east, in the order ticked)"));
    f.append(vehicles);
    const create = el("button", "Create", "write");
    create.type = "submit";
    create.id = "team-create";
    f.append(create);
    const said = el("p", "", "note");
    said.id = "team-create-result";
    said.setAttribute("role", "status");
    f.append(said);
    f.addEventListener("submit", (e) => { e.preventDefault(); submit(f, said); });
    box.append(f);
  }

  function vehicleChoices(list) {
    const box = document.getElementById("team-vehicles");
    const names = list.map((v) => v.name).join(",");
    if (box.dataset.names === names) return;
    box.dataset.names = names;
    box.querySelectorAll(".team-vehicle").forEach((n) => n.remove());
    for (const v of list) {
      const row = el("span", "", "team-vehicle");
      const tick = el("input");
      Object.assign(tick, { type: "checkbox", checked: true, value: v.name });
      tick.dataset.vehicle = v.name;
      const label = el("label", ` ${v.name} `);
      label.prepend(tick);
      const lost = el("select");
      lost.dataset.lost = v.name;
      lost.title = `what ${v.name} does if the link is lost during the survey (its own: ${v.lost_action})`;
      for (const [value, text] of [["", "its own lost-link action"], ["hold", "hold"], ["surface", "surface"], ["return", "return home"]]) {
        const option = el("option", text);
        option.value = value;
        lost.append(option);
      }
      row.append(label, lost);
      box.append(row);
    }
  }

  function body(f) {
    const value = (name) => Number(f.querySelector(`[name=${name}]`).value);
    const vehicles = [...f.querySelectorAll("[data-vehicle]")].filter((t) => t.checked).map((t) => {
      const lost = f.querySelector(`[data-lost="${t.value}"]`).value;
      return lost ? { vehicle: t.value, lost_action: lost } : { vehicle: t.value };
    });
    return {
      name: f.querySelector("[name=name]").value,
      spacing: value("spacing"),
      depth: value("depth"),
      area: { south: value("south"), north: value("north"), west: value("west"), east: value("east") },
      vehicles,
    };
  }

  function submit(f, said) {
    said.className = "note";
    said.textContent = "creating...";
    call("/teams", "POST", body(f))
      .then((t) => { said.textContent = `team mission ${t.id} (${t.name}) created: ${t.link.legs} legs; press Start below`; })
      .catch((e) => { said.className = "error"; said.textContent = `not created: ${e.message}`; })
      .finally(refresh);
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

  function proposals(list) {
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

  function act(team, action) {
    const ask = action === "delete" ? call(`/teams/${team.id}`, "DELETE") : call(`/teams/${team.id}/${action}`, "POST");
    outcome.set(team.id, { text: `${action}...`, error: false });
    ask.then(() => outcome.set(team.id, { text: `${action}: done`, error: false }))
      .catch((e) => outcome.set(team.id, { text: `${action} refused: ${e.message}`, error: true }))
      .finally(refresh);
  }

  function teams(list) {
    const box = document.getElementById("team-list");
    box.replaceChildren();
    if (!list.length) box.append(el("p", "none yet: create one above", "note"));
    for (const t of list.slice(0, 5)) {
      const item = el("div", "", "team");
      item.dataset.team = String(t.id);
      const head = el("p");
      head.append(el("strong", `${t.name} (#${t.id})`), ` ${t.status}, ${t.link.legs} legs, about ${t.link.channel_s_per_leg} s of the channel each `);
      if (canWrite) {
        for (const action of ACTIONS[t.status] || []) {
          const button = el("button", action[0].toUpperCase() + action.slice(1), action === "delete" ? "write danger" : "write");
          button.type = "button";
          button.dataset.action = action;
          button.addEventListener("click", () => act(t, action));
          head.append(button);
        }
      }
      item.append(head);
      const said = outcome.get(t.id);
      const why = said ? said : (t.status === "refused" ? { text: `start refused: ${t.detail}`, error: true } : null);
      if (why) {
        const line = el("p", why.text, why.error ? "error team-outcome" : "note team-outcome");
        line.setAttribute("role", why.error ? "alert" : "status");
        item.append(line);
      }
      const table = el("table");
      for (const m of t.members) {
        const tr = el("tr");
        const leg = m.stopping ? "stopping its own work first" : `leg ${Math.min(m.next + 1, m.waypoints.length)} of ${m.waypoints.length}`;
        for (const text of [m.name, m.state, leg, `lost link: ${m.lost_action}`, m.reason]) tr.append(el("td", text));
        table.append(tr);
      }
      item.append(table);
      box.append(item);
    }
  }

  async function refresh() {
    if (!token() || document.getElementById("main").hidden) return;
    if (!document.getElementById("team-card")) card();
    try {
      const [who, safety, props, list, vehicles] = await Promise.all(
        ["/whoami", "/safety", "/proposals", "/teams", "/vehicles"].map((path) => call(path)));
      canWrite = who.role === "write";
      document.getElementById("team-form").hidden = !canWrite;
      vehicleChoices(vehicles);
      warnings(safety);
      proposals(props);
      teams(list);
    } catch (e) {
      document.getElementById("team-result").textContent = `team missions: ${e.message}`;
    }
  }

  setInterval(refresh, REFRESH_MS);
  window.addEventListener("load", refresh);
})();
