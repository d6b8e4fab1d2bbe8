// Chat page: messages go to the chat bot and the avatar speaks the reply, either whole
// (api/chat's speech) or, with Streaming, clause by clause as the bot writes it over the
// api/stream WebSocket; one chat session carries the conversation on. The Talk button animates
// the microphone live over the api/listen WebSocket.
import { startApp } from './app.js';
import { requestChat, sessionGone, streamChat, streamSpeech } from './server.js';

const $ = (id) => document.getElementById(id);
const LANGUAGE_NAMES = { sv: 'Svenska', en: 'English' }; // the rest: the names the server sends
const status = $('status');
const show = (message) => {
  status.textContent = message;
  status.hidden = !message;
};

function addMessage(who, text) {
  const item = document.createElement('li');
  item.className = `message ${who}`;
  item.textContent = text;
  $('log').appendChild(item);
  item.scrollIntoView({ block: 'end' });
  return item;
}

function fillSelect(select, values, chosen, label = (v) => v) {
  for (const value of values) select.add(new Option(label(value), value, false, value === chosen));
}

async function setup(app) {
  const { config } = app;
  const names = { ...(config.language_names || {}), ...LANGUAGE_NAMES };
  const initial = config.languages.includes('en') ? 'en' : config.languages[0]; // English, as everywhere else
  fillSelect($('language'), config.languages, initial, (v) => names[v] || v);
  // Send asks the chat bot, which may answer in some languages only; Say speaks any of them.
  const chatLanguages = config.chat_languages || null;
  const chatRefused = () => chatLanguages !== null && !chatLanguages.includes($('language').value);
  const updateSend = () => {
    const language = $('language').value;
    const refused = chatRefused();
    $('send').disabled = refused;
    $('send').title = refused
      ? `The chat bot answers in ${chatLanguages.map((v) => names[v] || v).join(' and ')}; Say speaks ${names[language] || language}.`
      : '';
  };
  $('language').onchange = updateSend;
  fillSelect($('model'), config.models, config.default_model);
  $('model').disabled = !config.models.length;
  if (config.max_text) $('text').maxLength = config.max_text;
  // a chat model (it answers in any language) writes as it goes: speak it as it comes
  if (config.chat_languages === null) $('stream').checked = true;
  let session = null; // the chat session: the server's id of this conversation
  if (config.offline) show('No vispeech server answered; start one with `vispeech serve`.');

  const settings = () => ({ language: $('language').value, model: $('model').value || null, stream: $('stream').checked });

  const say = (text, { language, model, stream }) => (stream
    ? streamSpeech(app.performer, { text, language, model })
    : app.speak(text, language, model));

  const busy = (on) => {
    for (const id of ['send', 'say']) $(id).disabled = on;
    if (!on) updateSend();
  };
  updateSend();

  // Talk: the microphone drives the avatar until the button is pressed again.
  let listening = null;
  const mic = $('mic');
  mic.hidden = !config.audio_model;
  mic.onclick = async () => {
    if (listening) {
      mic.disabled = true;
      listening.stop();
      return;
    }
    show('');
    busy(true);
    mic.disabled = true;
    try {
      await app.performer.unlock();
      listening = await app.listen(null, show);
      mic.textContent = 'Stop';
      mic.classList.add('live');
      mic.disabled = false;
      await listening.done;
    } catch (err) {
      show(err.message);
    } finally {
      listening = null;
      mic.textContent = 'Talk';
      mic.classList.remove('live');
      mic.disabled = false;
      busy(false);
    }
  };

  const chatWith = async (message, options) => {
    if (options.stream) {
      const item = addMessage('bot', '');
      await streamChat(app.performer, { message, language: options.language, session, model: options.model }, (reply) => {
        session = reply.session;
        item.textContent = item.textContent ? `${item.textContent} ${reply.text}` : reply.text;
        item.scrollIntoView({ block: 'end' });
      }).catch((err) => {
        if (!item.textContent) item.remove();
        throw err;
      });
      return;
    }
    const answer = await requestChat({ message, language: options.language, session, ...app.lifeOptions() });
    session = answer.session;
    addMessage('bot', answer.reply);
    await app.playSpeech(answer.speech);
  };

  const submit = async (chat) => {
    const text = $('text').value.trim();
    if (!text) return;
    const options = settings();
    show('');
    busy(true);
    try {
      await app.performer.unlock();
      if (!chat) {
        addMessage('user said', text);
        $('text').value = '';
        await say(text, options);
        return;
      }
      addMessage('user', text);
      $('text').value = '';
      await chatWith(text, options).catch((err) => {
        if (!sessionGone(err)) throw err;
        session = null; // the server no longer holds the conversation: start a new one
        return chatWith(text, options);
      });
    } catch (err) {
      show(err.message);
    } finally {
      busy(false);
    }
  };

  $('form').onsubmit = (e) => {
    e.preventDefault();
    submit(!chatRefused());
  };
  $('say').onclick = () => submit(false);
  $('text').onkeydown = (e) => {
    if (e.key === 'Enter' && !e.shiftKey) {
      e.preventDefault();
      submit(!chatRefused()); // in a language the bot does not answer in, Enter says the text
    }
  };
}

startApp({ stage: $('stage'), setup, report: show }).catch((err) => show(err.message));
