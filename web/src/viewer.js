// Viewer page: the avatar alone. URL options: anim=URL and audio=URL (play them; the audio
// defaults to the one a vispeech JSON names),
// t=seconds (hold the pose at that time instead of playing), plus startApp's avatar / idle.
import { audioFor, fetchBody, startApp, toAnimation } from './app.js';

const status = document.getElementById('status');
const show = (message) => {
  status.textContent = message;
  status.hidden = !message;
};

async function setup(app) {
  const params = new URLSearchParams(window.location.search);
  const anim = params.get('anim');
  if (anim) {
    const hold = params.has('t');
    const animation = toAnimation(await fetchBody(anim, 'text'), anim);
    await app.playAnimation(animation, audioFor(animation, anim, params.get('audio')), { autoplay: !hold });
    if (hold) app.seek(Number(params.get('t')));
  }
}

startApp({ stage: document.getElementById('stage'), setup, report: show }).catch((err) => show(err.message));
