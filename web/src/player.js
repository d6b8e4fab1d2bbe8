// Player page: open an animation file (and its audio) from disk, by drag and drop, or with
// ?anim=URL&audio=URL (the audio defaults to the one a vispeech JSON names), and play it on
// the avatar with a scrub bar.
import { audioFor, fetchBody, startApp, toAnimation } from './app.js';

const $ = (id) => document.getElementById(id);
const status = $('status');
const show = (message) => {
  status.textContent = message;
  status.hidden = !message;
};

async function setup(app) {
  const { performer } = app;
  let animName = null;
  let audioName = null;
  let audio = null;
  let scrubbing = false;

  const loaded = () => {
    $('loaded').textContent = animName ? `${animName}${audioName ? ` + ${audioName}` : ' (no audio)'}` : '';
    for (const id of ['play', 'scrub']) $(id).disabled = !performer.animation;
    $('scrub').max = performer.duration.toFixed(3);
  };
  const openAnimation = (text, name) => {
    performer.load(toAnimation(text, name), audio);
    animName = name;
    loaded();
  };
  const openAudio = async (bytes, name) => {
    audio = await performer.decodeAudio(bytes);
    audioName = name;
    if (performer.animation) performer.load(performer.animation, audio);
    loaded();
  };
  const isAudio = (file) => file.type.startsWith('audio/') || /\.(wav|mp3|ogg|flac|m4a)$/i.test(file.name);
  // Open the files, the audio first, and show what went wrong with any of them (each named).
  const openFiles = async (files) => {
    const errors = [];
    for (const file of [...files].sort((a, b) => isAudio(b) - isAudio(a))) {
      try {
        if (isAudio(file)) await openAudio(await file.arrayBuffer(), file.name);
        else openAnimation(await file.text(), file.name);
      } catch (err) {
        errors.push(err.message.startsWith(`${file.name}: `) ? err.message : `${file.name}: ${err.message}`);
      }
    }
    show(errors.join('; '));
  };

  $('anim-file').onchange = (e) => openFiles(e.target.files);
  $('audio-file').onchange = (e) => openFiles(e.target.files);
  document.addEventListener('dragover', (e) => e.preventDefault());
  document.addEventListener('drop', (e) => {
    e.preventDefault();
    openFiles(e.dataTransfer.files);
  });
  $('play').onclick = () => (performer.state === 'playing' || performer.state === 'waiting' ? app.pause() : app.play());
  $('scrub').oninput = (e) => {
    scrubbing = true;
    app.seek(Number(e.target.value));
  };
  $('scrub').onchange = () => {
    scrubbing = false;
  };

  const update = () => {
    const t = Math.min(app.clock(), performer.duration);
    if (!scrubbing && performer.animation) $('scrub').value = String(t);
    $('time').textContent = `${t.toFixed(2)} / ${performer.duration.toFixed(2)} s`;
    const anim = performer.animation;
    const phone = anim && performer.state !== 'idle' ? anim.phoneAt(t) : null;
    const word = phone && Number.isInteger(phone.word) ? anim.phones.words[phone.word] : null;
    $('phone').textContent = phone ? `${phone.symbol}${word ? `  ·  ${word.text}` : ''}` : '\u00a0';
    requestAnimationFrame(update);
  };
  requestAnimationFrame(update);

  const params = new URLSearchParams(window.location.search);
  const animUrl = params.get('anim');
  if (animUrl) {
    openAnimation(await fetchBody(animUrl, 'text'), animUrl);
    const audioUrl = audioFor(performer.animation, animUrl, params.get('audio'));
    if (audioUrl) await openAudio(await fetchBody(audioUrl, 'arrayBuffer'), audioUrl.split('/').pop());
    app.play(0);
  }
}

startApp({
  stage: $('stage'),
  setup,
  report: show,
  onstate: (state) => {
    $('play').textContent = state === 'playing' || state === 'waiting' ? 'Pause' : 'Play';
  },
}).catch((err) => show(err.message));
