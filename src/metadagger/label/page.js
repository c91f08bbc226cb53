// The labelling page: polls the command for the state asked now, shows it, and sends the person's label.
// While the page is visible and shows a state, each poll says so ("shows"): the state's clock runs only then.
"use strict";

const token = document.body.dataset.token;
const $ = (id) => document.getElementById(id);
const api = (path, params = {}) => `api/${path}?${new URLSearchParams({ ...params, token })}`;

let view = null;        // the command's last view
let shown = "";         // "round/step" of the state on screen
let formKind = "";      // "classes" or "sliders", once built
let selected = null;    // the class chosen with the arrow keys
let clip = { id: -1, image: null, frames: 0, at: 0 };
let sending = false;
let ended = false;      // the command that served this page is gone for good (a new run has a new token)

// "round/step" of the state this page shows a person now: loaded, visible, not paused; else "".
function showing() {
  const ready = $("state").dataset.ready === "1";
  return ready && !document.hidden && view && view.status === "asking" ? shown : "";
}

async function poll() {
  try {
    const now = showing();
    const response = await fetch(api("view", now ? { shows: now } : {}));
    if (response.status === 403) {
      ended = true;
      end("This page's session has ended: the command was stopped and run again, with a new token. Open the URL " +
        "it printed last (every label given is kept).");
      return;
    }
    if (!response.ok) throw new Error(await response.text());
    show(await response.json());
  } catch (error) {
    $("message").textContent = "no connection to the command: it ended or was stopped. Run it again and open the " +
      "URL it prints (every label given is kept).";
    document.body.dataset.status = "offline";
  }
  if (view && view.status === "done") return;  // the command ends now: the page keeps its last words
  const every = view && view.status === "asking" ? view.poll * 1000 : 700;
  setTimeout(poll, every);
}

// Tell the command which state this page shows now ("" for none); kept alive while the page closes.
function tell(state) {
  if (ended) return;
  fetch(api("view", { shows: state }), { keepalive: true }).catch(() => {});
}

function end(message) {
  document.body.dataset.status = "ended";
  $("message").textContent = message;
  clearState();
}

function clearState() {
  const box = $("state");
  box.dataset.ready = "0";
  box.dataset.round = box.dataset.step = "";
  $("frame").removeAttribute("src");
  $("overview").removeAttribute("src");
  $("where").textContent = "";
  $("around").replaceChildren();
}

function show(v) {
  view = v;
  document.body.dataset.status = v.status;
  $("title").textContent = v.title;
  const round = v.asked ? `; this round ${v.answered} of ${v.asked}` : "";
  $("progress").textContent = `round ${v.round} of ${v.rounds}; queries so far ${v.queries}${round}`;
  $("message").textContent = v.status === "paused" ? "paused: press Space to go on" : v.message;
  buildForm(v.form);
  showClip(v.clip);
  $("overviewbox").hidden = !v.overview;
  $("overviewcaption").textContent = v.overview || "";
  const state = v.state;
  const key = state ? `${state.round}/${state.step}` : "";
  if (key === shown) return;
  shown = key;
  if (!state) {
    clearState();
    return;
  }
  const box = $("state");
  box.dataset.ready = "0";
  $("error").textContent = "";
  $("frame").onload = () => {
    box.dataset.round = String(state.round);
    box.dataset.step = String(state.step);
    box.dataset.ready = "1";
    tell(showing());  // the state is on screen: its clock starts now, not at the next poll
  };
  // a URL of its own: the browser would reuse a frame it loaded among the steps around
  $("frame").src = api("frame", { round: state.round, step: state.step, shown: 1 });
  if (state.overview) $("overview").src = api("overview", { round: state.round, step: state.step });
  else $("overview").removeAttribute("src");
  $("where").textContent = `step ${state.step} of ${state.steps} (0-based)`;
  if ($("around").classList.contains("open")) showAround();
}

function buildForm(form) {
  const kind = form.classes ? "classes" : "sliders";
  if (kind === formKind) return;
  formKind = kind;
  $("asks").textContent = form.asks;
  const box = $("form");
  box.replaceChildren();
  if (form.classes) {
    const row = document.createElement("div");
    row.id = "classes";
    form.classes.forEach((name, index) => {
      const column = document.createElement("div");
      column.className = "class";
      const button = document.createElement("button");
      button.textContent = name;
      button.dataset.label = String(index);
      button.addEventListener("click", () => { button.blur(); choose(index); give(index); });
      const mark = document.createElement("span");
      mark.className = "mark";
      mark.textContent = form.marks[String(index)] || "";
      column.append(button, mark);
      row.append(column);
    });
    box.append(row);
    choose(Math.floor(form.classes.length / 2));
    return;
  }
  form.sliders.forEach((slider, index) => {
    const line = document.createElement("div");
    line.className = "slider";
    const name = document.createElement("label");
    name.textContent = slider.name;
    const range = document.createElement("input");
    Object.assign(range, { type: "range", min: slider.low, max: slider.high, step: "any", value: 0 });
    const typed = document.createElement("input");
    Object.assign(typed, { type: "number", min: slider.low, max: slider.high, step: "any", value: 0 });
    typed.dataset.dimension = String(index);
    range.addEventListener("input", () => { typed.value = range.value; });
    typed.addEventListener("input", () => { range.value = typed.value; });
    line.append(name, range, typed);
    box.append(line);
  });
  const button = document.createElement("button");
  button.id = "give";
  button.textContent = "Give label";
  button.addEventListener("click", giveSliders);
  box.append(button);
}

function choose(index) {
  const buttons = document.querySelectorAll("#classes button");
  selected = Math.max(0, Math.min(buttons.length - 1, index));
  buttons.forEach((b, i) => b.classList.toggle("selected", i === selected));
}

function giveSliders() {
  const values = [...document.querySelectorAll("#form input[type=number]")].map((input) => Number(input.value));
  give(values);
}

async function give(label) {
  const state = view && view.state;
  if (!state || sending || $("state").dataset.ready !== "1") return;
  sending = true;
  try {
    const response = await fetch(api("label"), {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ round: state.round, step: state.step, label }),
    });
    const answer = await response.json();
    if (!response.ok) $("error").textContent = answer.error;
    else show(answer);
  } catch (error) {
    $("error").textContent = "the label did not reach the command (not kept): give it again once it runs";
  } finally {
    sending = false;
  }
}

async function pause() {
  const response = await fetch(api("pause"), {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ paused: view.status !== "paused" }),
  });
  if (response.ok) show(await response.json());
}

function showAround() {
  const state = view && view.state;
  const box = $("around");
  box.replaceChildren();
  if (!state) return;
  for (let step = state.step - state.neighbours; step <= state.step + state.neighbours; step++) {
    if (step < 0 || step >= state.steps) continue;
    const figure = document.createElement("figure");
    if (step === state.step) figure.className = "now";
    const image = document.createElement("img");
    image.className = "pixels";
    image.src = api("frame", { round: state.round, step });
    const caption = document.createElement("figcaption");
    caption.textContent = String(step);
    figure.append(image, caption);
    box.append(figure);
  }
}

function showClip(info) {
  if (!info || info.id === clip.id) return;
  const image = new Image();
  image.onload = () => { clip = { id: info.id, image, frames: info.frames, at: 0 }; };
  image.src = api("clip", { id: info.id });
  const outcome = info.success ? "success" : "failure";
  $("clipinfo").textContent = `${info.steps} steps, ${outcome}, reward ${info.reward}`;
}

function playClip() {
  if (clip.image) {
    const canvas = $("clip");
    const width = clip.image.width / clip.frames;
    canvas.width = width;
    canvas.height = clip.image.height;
    canvas.getContext("2d").drawImage(clip.image, clip.at * width, 0, width, clip.image.height, 0, 0, width,
      clip.image.height);
    clip.at = (clip.at + 1) % clip.frames;
  }
  setTimeout(playClip, 125);
}

document.addEventListener("keydown", (event) => {
  if (!view) return;
  const typing = event.target instanceof HTMLInputElement;
  if (event.key === " " && !typing) { event.preventDefault(); pause(); return; }
  if ((event.key === "a" || event.key === "A") && !typing) {
    $("around").classList.toggle("open");
    showAround();
    return;
  }
  if (formKind === "classes") {
    if (event.key === "ArrowLeft") { event.preventDefault(); choose(selected - 1); }
    else if (event.key === "ArrowRight") { event.preventDefault(); choose(selected + 1); }
    else if (event.key === "Enter") { event.preventDefault(); give(selected); }
  } else if (event.key === "Enter") {
    event.preventDefault();
    giveSliders();
  }
});

// a hidden or closed page shows no state: its clock stops at once, not after the command's wait for a silent page
document.addEventListener("visibilitychange", () => tell(showing()));
window.addEventListener("pagehide", () => tell(""));

poll();
playClip();
