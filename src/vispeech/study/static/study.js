// The participant's page of a vispeech perceptual study (vispeech/study/app.py).
// The faces of a trial are cropped from composite clips into canvases labelled A, B, ...;
// the answer is enabled once the clip has played to its end; each answer is committed by the
// server before the next trial is shown.
"use strict";

const $ = (id) => document.getElementById(id);
const LETTERS = "ABCDEFGHIJ";
let study = null;
let state = null; // {trials, next, finished}
let shownAt = 0;
let media = []; // the current trial's video elements
let drawing = 0;

function show(section) {
  for (const id of ["welcome", "trial", "done"]) $(id).hidden = id !== section;
}

function fail(message) {
  $("error").textContent = message;
  $("error").hidden = !message;
}

async function api(path, body) {
  const options = body === undefined ? {} : {
    method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body),
  };
  const response = await fetch(path, options);
  const data = await response.json().catch(() => ({detail: `HTTP ${response.status}`}));
  if (!response.ok) throw Object.assign(new Error(data.detail || `HTTP ${response.status}`), {status: response.status});
  return data;
}

function welcome() {
  $("intro").textContent = study.intro;
  $("consent-text").textContent = study.consent;
  const box = $("questions");
  box.replaceChildren();
  for (const q of study.questions) {
    const set = document.createElement("fieldset");
    const legend = document.createElement("legend");
    legend.textContent = q.text;
    set.append(legend);
    q.choices.forEach((choice, k) => {
      const label = document.createElement("label");
      const input = Object.assign(document.createElement("input"),
        {type: "radio", name: q.id, value: choice, required: true, id: `q-${q.id}-${k}`});
      label.append(input, ` ${choice} `);
      set.append(label);
    });
    box.append(set);
  }
  show("welcome");
}

// The participant id the link carries (a recruitment platform's), if any.
function linkPid() {
  const params = new URLSearchParams(location.search);
  return params.get("pid") || params.get("PROLIFIC_PID") || undefined;
}

// This browser's participant, if it is the link's (a shared browser may hold another's cookie).
function me() {
  const pid = linkPid();
  return api(pid === undefined ? "/api/me" : `/api/me?pid=${encodeURIComponent(pid)}`);
}

async function join(event) {
  event.preventDefault();
  const intro = {};
  for (const q of study.questions) {
    const picked = document.querySelector(`input[name="${q.id}"]:checked`);
    if (picked) intro[q.id] = picked.value;
  }
  try {
    fail("");
    state = await api("/api/join", {consent: $("consent").checked, pid: linkPid(), intro});
    next();
  } catch (error) {
    fail(error.message);
  }
}

function stopMedia() {
  cancelAnimationFrame(drawing);
  for (const video of media) { video.pause(); video.removeAttribute("src"); video.load(); }
  media = [];
}

function drawFaces(faces, canvases, videos) {
  faces.forEach((face, k) => {
    const video = videos.get(face.clip);
    if (!video.videoWidth) return;
    const width = video.videoWidth / face.columns;
    const canvas = canvases[k];
    if (canvas.width !== Math.round(width)) {
      canvas.width = Math.round(width);
      canvas.height = video.videoHeight;
    }
    canvas.getContext("2d").drawImage(video, face.column * width, 0, width, video.videoHeight,
      0, 0, canvas.width, canvas.height);
  });
}

function next() {
  stopMedia();
  if (state.finished || state.next >= state.trials.length) {
    $("thanks").textContent = study.thanks;
    show("done");
    return;
  }
  const trial = state.trials[state.next];
  $("count").textContent = study.labels.item.replace("{n}", state.next + 1).replace("{total}", state.trials.length);
  $("question").textContent = trial.task === "rating" ? study.rating_question : study.pairwise_question;

  const videos = new Map();
  for (const url of new Set([...trial.faces.map((f) => f.clip), trial.audio])) {
    const video = Object.assign(document.createElement("video"),
      {src: url, preload: "auto", muted: url !== trial.audio, playsInline: true});
    video.muted = url !== trial.audio;
    videos.set(url, video);
  }
  media = [...videos.values()];
  const canvases = trial.faces.map(() => document.createElement("canvas"));
  $("faces").replaceChildren(...trial.faces.map((face, k) => {
    const box = document.createElement("div");
    box.className = "face";
    const label = document.createElement("span");
    label.textContent = LETTERS[k];
    canvases[k].dataset.slot = LETTERS[k];
    box.append(canvases[k], label);
    return box;
  }));
  for (const video of media) video.addEventListener("loadeddata", () => drawFaces(trial.faces, canvases, videos));

  const sound = videos.get(trial.audio);
  let heard = false;
  $("hint").hidden = false;
  $("play").disabled = false;
  $("play").onclick = async () => {
    $("play").disabled = true;
    for (const video of media) video.currentTime = 0;
    const loop = () => { drawFaces(trial.faces, canvases, videos); drawing = requestAnimationFrame(loop); };
    try {
      await Promise.all(media.map((video) => video.play()));
    } catch (error) {
      fail(`the clip could not be played: ${error.message}`);
      $("play").disabled = false;
      return;
    }
    loop();
  };
  sound.addEventListener("ended", () => {
    cancelAnimationFrame(drawing);
    for (const video of media) video.pause();
    drawFaces(trial.faces, canvases, videos);
    $("play").disabled = false;
    $("play").textContent = study.labels.play_again;
    if (!heard) { heard = true; enableAnswers(trial); }
  });
  $("play").textContent = study.labels.play;
  $("ratings").hidden = true;
  $("choices").hidden = true;
  $("next").hidden = true;
  buildAnswers(trial);
  show("trial");
  shownAt = performance.now();
}

function buildAnswers(trial) {
  if (trial.task === "pairwise") {
    for (const button of $("choices").querySelectorAll("button")) {
      button.disabled = true;
      button.onclick = () => send(button.dataset.answer);
    }
    return;
  }
  const box = $("ratings");
  const anchors = Object.entries(study.anchors).map(([value, text]) => `${value} = ${text}`).join(" · ");
  const legend = Object.assign(document.createElement("p"), {className: "hint", textContent: anchors});
  const rows = trial.faces.map((face, k) => {
    const row = document.createElement("div");
    row.className = "row";
    row.append(Object.assign(document.createElement("b"), {textContent: LETTERS[k]}));
    for (let value = 1; value <= 9; value++) {
      const label = document.createElement("label");
      const input = Object.assign(document.createElement("input"),
        {type: "radio", name: `rate-${k}`, value: String(value), disabled: true, id: `rate-${LETTERS[k]}-${value}`});
      input.onchange = () => {
        $("next").disabled = trial.faces.some((_, j) => !document.querySelector(`input[name="rate-${j}"]:checked`));
      };
      label.append(input, String(value));
      row.append(label);
    }
    return row;
  });
  box.replaceChildren(legend, ...rows);
  $("next").disabled = true;
  $("next").onclick = () => send(trial.faces.map((_, j) =>
    Number(document.querySelector(`input[name="rate-${j}"]:checked`).value)));
}

function enableAnswers(trial) {
  $("hint").hidden = true;
  if (trial.task === "pairwise") {
    $("choices").hidden = false;
    for (const button of $("choices").querySelectorAll("button")) button.disabled = false;
  } else {
    $("ratings").hidden = false;
    for (const input of $("ratings").querySelectorAll("input")) input.disabled = false;
    $("next").hidden = false;
  }
}

async function send(answer) {
  const ms = Math.round(performance.now() - shownAt);
  for (const button of document.querySelectorAll("#choices button, #next")) button.disabled = true;
  try {
    fail("");
    state = await api("/api/answers", {trial: state.next, answer, ms});
    next();
  } catch (error) {
    if (error.status === 409) {
      state = await me();
      next();
      return;
    }
    fail(`${error.message}: ${study.labels.not_saved}`);
    for (const button of document.querySelectorAll("#choices button, #next")) button.disabled = false;
  }
}

async function start() {
  try {
    study = await api("/api/study");
  } catch (error) {
    fail(error.message);
    return;
  }
  document.title = study.title;
  $("title").textContent = study.title;
  $("start").textContent = study.labels.start;
  $("next").textContent = study.labels.next;
  $("choose-tie").textContent = study.labels.tie;
  $("hint").textContent = study.labels.listen_first;
  $("join").addEventListener("submit", join);
  try {
    state = await me();
    next();
  } catch (error) {
    if (error.status === 404) welcome();
    else fail(error.message);
  }
}

start();
