/* vispeech 2D face: a frontal, stylised face drawn on a <canvas> and driven by ARKit
 * blend-shape weights (jaw, lips, teeth, tongue, eyes, brows).
 *
 * Plain browser script: no modules, no dependencies, no network. It defines one global,
 * `VispeechFace2D`, holding
 *
 *   Face2D      new VispeechFace2D.Face2D(canvas[, {background: "#fff"}])
 *               face.setWeights({jawOpen: 0.5, mouthClose: 0, ...}[, timeSeconds])
 *               face.draw([timeSeconds])    redraw with the current weights
 *               face.resize()               re-read the canvas' CSS size (call on window resize)
 *   mouthShape  mouthShape(weights) -> lip contours, opening and jaw drop (drawing units)
 *   CHANNELS    the channels the face reads: ARKit's, and vispeech's own tongue channels
 *               tongueTipUp, tongueBodyUp and tongueBack (see vispeech.postprocess.tongue)
 *
 * Weights are channel values in [0, 1]; a missing channel is 0. `timeSeconds` drives
 * idle blinks (a fixed pseudo-random schedule, so a given time always looks the same); when it
 * is left out the page clock (performance.now) is used. "Left" channels move the subject's
 * left side, which is the viewer's right. The drawing lives in a 400 x 500 unit box scaled to
 * fit the canvas.
 */
(function (root) {
  "use strict";

  var WIDTH = 400, HEIGHT = 500;      // drawing units
  var CX = 200;                       // face centre line
  var MOUTH_Y = 312;                  // lip line at rest
  var MOUTH_HALF_WIDTH = 42;
  var UPPER_LIP = 11.5, LOWER_LIP = 15.5; // lip heights at the centre
  var JAW_DROP = 60;                  // chin travel at jawOpen = 1
  var UPPER_TEETH_EDGE = MOUTH_Y + 3;
  var SAMPLES = 41;                   // points along each lip contour

  var CHANNELS = [
    "jawOpen", "jawForward", "jawLeft", "jawRight",
    "mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight",
    "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthUpperUpLeft", "mouthUpperUpRight", "cheekPuff", "tongueOut",
    "tongueTipUp", "tongueBodyUp", "tongueBack",
    "eyeBlinkLeft", "eyeBlinkRight", "eyeWideLeft", "eyeWideRight",
    "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight",
    "eyeLookUpLeft", "eyeLookUpRight", "eyeLookDownLeft", "eyeLookDownRight",
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "noseSneerLeft", "noseSneerRight"
  ];

  var COLORS = {
    skin: "#eec19f", skinEdge: "#dca27e", skinLine: "rgba(150, 88, 62, 0.55)",
    hair: "#4b3427", hairLight: "#6a4a37", lipUpper: "#b4545b", lipLower: "#c4656b",
    lipLine: "#6b2429", cavity: "#3b1116", cavityDeep: "#1d0608", gum: "#c9646c",
    tooth: "#f7f3ea", toothEdge: "#c8bfae", tongue: "#dc7480", tongueBody: "#c4606d",
    tongueDark: "#b04c5a",
    eyeWhite: "#fbfaf7", iris: "#4f7a8f", pupil: "#1b2328", lash: "#2d1f18", brow: "#4b3427"
  };

  function clamp01(x) { return x < 0 ? 0 : x > 1 ? 1 : x; }
  function lerp(a, b, t) { return a + (b - a) * t; }
  function bump(x, centre, width) { var d = (x - centre) / width; return Math.exp(-d * d); }

  /* One weight, clamped to [0, 1]; missing or non-numeric values are 0. */
  function weight(weights, name) {
    var v = Number(weights[name]);
    return isFinite(v) ? clamp01(v) : 0;
  }

  /* The mouth corner on one side; side -1 is the viewer's left (the subject's right). */
  function corner(weights, suffix, side, common) {
    var g = function (n) { return weight(weights, n + suffix); };
    var smile = g("mouthSmile"), stretch = g("mouthStretch"), frown = g("mouthFrown");
    var widen = 1 + 0.22 * smile + 0.28 * stretch + 0.08 * g("mouthDimple")
      - 0.36 * common.pucker - 0.24 * common.funnel - 0.08 * common.gap / JAW_DROP;
    return {
      x: CX + common.shift + side * MOUTH_HALF_WIDTH * widen,
      y: common.y + 0.3 * common.gap - 9 * smile + 6 * frown + 2.5 * stretch,
      upperUp: g("mouthUpperUp"), lowerDown: g("mouthLowerDown"),
      smile: smile, stretch: stretch
    };
  }

  /* Lip contours for the given weights, in drawing units.
   *
   * Returns {x, upperInner, lowerInner} and {xOuter, upperOuter, lowerOuter} (arrays of SAMPLES
   * numbers from the viewer's left corner to the right one; the outer contours reach a little
   * past the corners), `opening` (gap
   * between the inner contours at the centre; exactly 0 when the lips are sealed), `seal`
   * (0 open .. 1 closed by mouthClose / mouthPress), `jawDrop`, `jawShift`, `tongueOut`,
   * `jawForward`, `corners` and `cheekPuff`; for the tongue inside the mouth `tipRaise`
   * (tongueTipUp, 0 while the tongue is out), `bodyRaise` (tongueBodyUp), `tongueBack`
   * (tongueBack) and `tongue` = {x, top, halfWidth, tipY, bodyY, bodyHalfWidth}: the centre
   * line, the upper edge and half width of its front part (which rides on the jaw and goes
   * lower and narrower as it is drawn back), the height its tip reaches (`top` at rest, up to
   * just behind the upper teeth's edge) and the height and half width of its body (hidden
   * behind the front part at rest, up to the palate line just above the upper teeth's edge).
   */
  function mouthShape(weights) {
    var g = function (n) { return weight(weights, n); };
    var jaw = g("jawOpen"), close = g("mouthClose");
    var pucker = g("mouthPucker"), funnel = g("mouthFunnel");
    var rollLower = g("mouthRollLower"), rollUpper = g("mouthRollUpper");
    var shrugLower = g("mouthShrugLower"), shrugUpper = g("mouthShrugUpper");
    var tongueOut = g("tongueOut");
    var tipUp = g("tongueTipUp"), bodyUp = g("tongueBodyUp"), back = g("tongueBack");
    var press = 0.5 * (g("mouthPressLeft") + g("mouthPressRight"));
    // mouthClose counts relative to the jaw (ARKit: mouthClose = jawOpen seals the lips).
    var seal = clamp01(Math.max(close / Math.max(jaw, 0.02), press));
    var open = 1 - seal;
    var jawDrop = JAW_DROP * jaw;
    var jawShift = 7 * (g("jawLeft") - g("jawRight"));
    var round = clamp01(pucker + funnel);
    var gap = 0.92 * jawDrop * open;
    var common = {
      gap: gap, pucker: pucker, funnel: funnel,
      shift: 9 * (g("mouthLeft") - g("mouthRight")) + 0.6 * jawShift,
      y: MOUTH_Y + 0.2 * jawDrop * seal - 2.5 * shrugUpper - 2 * shrugLower
    };
    var left = corner(weights, "Right", -1, common);
    var right = corner(weights, "Left", 1, common);

    var tU = (1 - 0.7 * rollUpper) * (1 - 0.3 * press) * (1 + 0.3 * pucker + 0.2 * funnel + 0.15 * shrugUpper)
      * (1 - 0.12 * 0.5 * (left.smile + right.smile));
    var tL = (1 - 0.65 * rollLower) * (1 - 0.3 * press) * (1 + 0.35 * pucker + 0.25 * funnel + 0.2 * shrugLower)
      * (1 - 0.15 * 0.5 * (left.stretch + right.stretch)) * (1 - 0.2 * seal * jaw);
    var shapePower = lerp(0.8, 0.5, round);
    var lipPower = lerp(0.55, 0.38, round);

    var overhang = 3 * (1 - 0.5 * round);   // the outer lip contours reach past the corners
    var out = { x: [], xOuter: [], upperOuter: [], upperInner: [], lowerInner: [], lowerOuter: [] };
    for (var i = 0; i < SAMPLES; i++) {
      var s = -1 + 2 * i / (SAMPLES - 1), a = Math.abs(s), u = (s + 1) / 2;
      var c = s < 0 ? left : right;
      var meet = common.y + (c.y - common.y) * s * s + 1.2 * bump(s, 0, 0.12);
      var upperUp = lerp(left.upperUp, right.upperUp, u);
      var lowerDown = lerp(left.lowerDown, right.lowerDown, u);
      var rise = 0.1 * gap + open * (8 * upperUp + 5 * rollLower + 4 * funnel + 3 * tongueOut);
      var fall = (0.9 * gap + open * (11 * lowerDown + 6 * funnel + 7 * tongueOut)) * (1 - 0.75 * rollLower);
      var shape = Math.pow(Math.max(0, 1 - a * a), shapePower);
      var lip = Math.pow(Math.max(0, 1 - a * a), lipPower);
      var cupid = 1 + 0.16 * bump(a, 0.3, 0.16) - 0.18 * bump(s, 0, 0.11);
      var upperInner = meet - rise * shape;
      var lowerInner = meet + fall * shape;
      out.x.push(lerp(left.x, right.x, u));
      out.xOuter.push(lerp(left.x - overhang, right.x + overhang, u));
      out.upperInner.push(upperInner);
      out.lowerInner.push(lowerInner);
      out.upperOuter.push(upperInner - UPPER_LIP * tU * lip * cupid);
      out.lowerOuter.push(lowerInner + LOWER_LIP * tL * lip);
    }
    var mid = (SAMPLES - 1) / 2;
    out.opening = out.lowerInner[mid] - out.upperInner[mid];
    out.seal = seal;
    out.jawDrop = jawDrop;
    out.jawShift = jawShift;
    out.jawForward = g("jawForward");
    out.tongueOut = tongueOut * open;
    // The tongue inside the mouth: the tip rises to the ridge behind the upper teeth (t d n l),
    // the body to the palate (k g), and a tongue drawn back shows less of its front.
    out.tipRaise = tipUp * (1 - tongueOut);
    out.bodyRaise = bodyUp;
    out.tongueBack = back;
    var tongueTop = MOUTH_Y + 0.75 * jawDrop - 3 + 6 * back;
    var ridge = Math.min(tongueTop, UPPER_TEETH_EDGE - 2), palate = Math.min(tongueTop, UPPER_TEETH_EDGE - 3);
    out.tongue = {
      x: CX + jawShift, top: tongueTop, halfWidth: 34 * (1 - 0.3 * back),
      tipY: lerp(tongueTop, ridge, out.tipRaise),
      bodyY: lerp(tongueTop + 6, palate, bodyUp), bodyHalfWidth: 28 * (1 - 0.2 * back)
    };
    out.corners = [left, right];
    out.cheekPuff = g("cheekPuff");
    out.rollLower = rollLower;
    return out;
  }

  /* Idle blink amount (0..1) at `t` seconds: one blink of 0.18 s in every 4 s window. */
  function idleBlink(t) {
    var period = 4.0, duration = 0.18;
    var k = Math.floor(t / period);
    var jitter = Math.abs(Math.sin(k * 12.9898 + 78.233) * 43758.5453) % 1;
    var dt = t - (k * period + 0.6 + 2.8 * jitter);
    return dt >= 0 && dt < duration ? Math.sin(Math.PI * dt / duration) : 0;
  }

  function Face2D(canvas, options) {
    if (!canvas || !canvas.getContext) throw new Error("Face2D needs a <canvas> element");
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.options = options || {};
    this.weights = {};
    this.time = null;
    this.resize();
  }

  Face2D.prototype.resize = function () {
    var c = this.canvas;
    var dpr = (root.devicePixelRatio || 1);
    var cssW = c.clientWidth || c.width, cssH = c.clientHeight || c.height;
    var w = Math.max(1, Math.round(cssW * dpr)), h = Math.max(1, Math.round(cssH * dpr));
    if (c.width !== w) c.width = w;
    if (c.height !== h) c.height = h;
    this.scale = Math.min(w / WIDTH, h / HEIGHT);
    this.offsetX = (w - WIDTH * this.scale) / 2;
    this.offsetY = (h - HEIGHT * this.scale) / 2;
  };

  /* Replace the weights (missing channels are 0) and redraw. */
  Face2D.prototype.setWeights = function (weights, timeSeconds) {
    this.weights = weights || {};
    this.draw(timeSeconds);
  };

  Face2D.prototype.draw = function (timeSeconds) {
    if (timeSeconds !== undefined && timeSeconds !== null) this.time = timeSeconds;
    var t = this.time !== null ? this.time
      : (root.performance ? root.performance.now() : Date.now()) / 1000;
    var ctx = this.ctx, w = this.weights, m = mouthShape(w);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
    if (this.options.background) {
      ctx.fillStyle = this.options.background;
      ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
    }
    ctx.setTransform(this.scale, 0, 0, this.scale, this.offsetX, this.offsetY);
    ctx.lineJoin = "round";
    ctx.lineCap = "round";
    drawNeck(ctx);
    drawEars(ctx);
    drawHead(ctx, m);
    drawHair(ctx);
    drawBrows(ctx, w);
    var blink = idleBlink(t);
    drawEye(ctx, w, CX - 52, -1, "Right", blink);
    drawEye(ctx, w, CX + 52, 1, "Left", blink);
    drawNose(ctx, w);
    drawFolds(ctx, m);
    drawMouth(ctx, m);
  };

  // ---- drawing ---------------------------------------------------------------------------

  function path(ctx, xs, ys, reverse, moveFirst) {
    var n = xs.length;
    for (var k = 0; k < n; k++) {
      var i = reverse ? n - 1 - k : k;
      if (k === 0 && moveFirst) ctx.moveTo(xs[i], ys[i]); else ctx.lineTo(xs[i], ys[i]);
    }
  }

  function drawNeck(ctx) {
    ctx.beginPath();
    ctx.moveTo(CX - 64, 330);
    ctx.bezierCurveTo(CX - 62, 420, CX - 70, 450, CX - 160, 478);
    ctx.quadraticCurveTo(CX - 200, 488, CX - 210, 510);
    ctx.lineTo(CX + 210, 510);
    ctx.quadraticCurveTo(CX + 200, 488, CX + 160, 478);
    ctx.bezierCurveTo(CX + 70, 450, CX + 62, 420, CX + 64, 330);
    ctx.closePath();
    ctx.fillStyle = COLORS.skinEdge;
    ctx.fill();
    ctx.beginPath();
    ctx.moveTo(CX - 150, 500);
    ctx.quadraticCurveTo(CX, 452, CX + 150, 500);
    ctx.lineTo(CX + 210, 510);
    ctx.lineTo(CX - 210, 510);
    ctx.closePath();
    ctx.fillStyle = "#5d7386";
    ctx.fill();
  }

  function drawEars(ctx) {
    for (var side = -1; side <= 1; side += 2) {
      var x = CX + side * 124;
      ctx.beginPath();
      ctx.ellipse(x, 222, 15, 31, side * 0.12, 0, 2 * Math.PI);
      ctx.fillStyle = COLORS.skinEdge;
      ctx.fill();
      ctx.beginPath();
      ctx.ellipse(x + side * 3, 222, 7, 20, side * 0.12, -Math.PI / 2, Math.PI / 2, side < 0);
      ctx.strokeStyle = COLORS.skinLine;
      ctx.lineWidth = 2;
      ctx.stroke();
    }
  }

  function headPath(ctx, m) {
    var d = m.jawDrop, js = m.jawShift, puff = 10 * m.cheekPuff;
    ctx.beginPath();
    ctx.moveTo(CX - 124, 205);
    ctx.ellipse(CX, 205, 124, 163, 0, Math.PI, 2 * Math.PI);
    // right cheek and jaw down to the chin, then up the left side
    ctx.bezierCurveTo(CX + 126, 265, CX + 118 + puff, 300 + 0.15 * d, CX + 104 + 0.5 * puff, 338 + 0.3 * d);
    ctx.bezierCurveTo(CX + 88, 372 + 0.55 * d, CX + 66 + js, 396 + 0.9 * d, CX + 34 + js, 405 + d);
    ctx.quadraticCurveTo(CX + js, 414 + d, CX - 34 + js, 405 + d);
    ctx.bezierCurveTo(CX - 66 + js, 396 + 0.9 * d, CX - 88, 372 + 0.55 * d, CX - 104 - 0.5 * puff, 338 + 0.3 * d);
    ctx.bezierCurveTo(CX - 118 - puff, 300 + 0.15 * d, CX - 126, 265, CX - 124, 205);
    ctx.closePath();
  }

  function drawHead(ctx, m) {
    headPath(ctx, m);
    var grad = ctx.createRadialGradient(CX, 250, 40, CX, 250, 200);
    grad.addColorStop(0, COLORS.skin);
    grad.addColorStop(0.7, COLORS.skin);
    grad.addColorStop(1, COLORS.skinEdge);
    ctx.fillStyle = grad;
    ctx.fill();
    ctx.strokeStyle = "rgba(120, 70, 50, 0.35)";
    ctx.lineWidth = 1.5;
    ctx.stroke();
    // chin crease and chin
    var d = m.jawDrop, js = m.jawShift, y = m.lowerOuter[(SAMPLES - 1) / 2];
    ctx.beginPath();
    ctx.moveTo(CX - 16 + js, y + 11);
    ctx.quadraticCurveTo(CX + js, y + 6, CX + 16 + js, y + 11);
    ctx.strokeStyle = COLORS.skinLine;
    ctx.lineWidth = 1.6;
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(CX - 14 + js, 396 + d);
    ctx.quadraticCurveTo(CX + js, 401 + d, CX + 14 + js, 396 + d);
    ctx.strokeStyle = "rgba(150, 88, 62, 0.3)";
    ctx.stroke();
  }

  function drawHair(ctx) {
    ctx.beginPath();
    ctx.moveTo(CX - 129, 200);
    ctx.ellipse(CX, 200, 130, 170, 0, Math.PI, 2 * Math.PI);
    ctx.bezierCurveTo(CX + 128, 170, CX + 124, 150, CX + 116, 140);
    ctx.bezierCurveTo(CX + 96, 104, CX + 50, 92, CX + 24, 88);
    ctx.bezierCurveTo(CX - 40, 96, CX - 96, 110, CX - 116, 150);
    ctx.bezierCurveTo(CX - 122, 162, CX - 124, 180, CX - 129, 200);
    ctx.closePath();
    var grad = ctx.createLinearGradient(0, 30, 0, 200);
    grad.addColorStop(0, COLORS.hairLight);
    grad.addColorStop(1, COLORS.hair);
    ctx.fillStyle = grad;
    ctx.fill();
  }

  function drawBrows(ctx, w) {
    var inner = weight(w, "browInnerUp");
    for (var side = -1; side <= 1; side += 2) {
      var suffix = side < 0 ? "Right" : "Left";
      var down = weight(w, "browDown" + suffix), outer = weight(w, "browOuterUp" + suffix);
      var yi = 160 - 8 * inner + 6 * down, yo = 162 - 8 * outer + 2 * down;
      ctx.beginPath();
      ctx.moveTo(CX + side * 28, yi + 4);
      ctx.quadraticCurveTo(CX + side * 50, yi - 8 - 2 * inner, CX + side * 80, yo + 4);
      ctx.strokeStyle = COLORS.brow;
      ctx.lineWidth = 6;
      ctx.stroke();
    }
  }

  function drawEye(ctx, w, x, side, suffix, idle) {
    var blink = Math.max(idle, weight(w, "eyeBlink" + suffix));
    var wide = weight(w, "eyeWide" + suffix);
    var y = 196, half = 22;
    var openness = (1 - blink) * (1 + 0.35 * wide);
    var top = y - 16 * openness + 9 * (1 - openness) * (blink > 0 ? 1 : 0);
    var bottom = y + 9;
    var xi = x - side * half, xo = x + side * half;   // inner and outer corners
    ctx.save();
    ctx.beginPath();
    ctx.moveTo(xi, y + 1);
    ctx.quadraticCurveTo(x - side * 4, top, xo, y - 1);
    ctx.quadraticCurveTo(x, bottom, xi, y + 1);
    ctx.closePath();
    ctx.fillStyle = COLORS.eyeWhite;
    ctx.fill();
    ctx.clip();
    var lookIn = weight(w, "eyeLookIn" + suffix), lookOut = weight(w, "eyeLookOut" + suffix);
    var ix = x + side * 7 * (lookOut - lookIn);
    var iy = y - 1 + 6 * (weight(w, "eyeLookDown" + suffix) - weight(w, "eyeLookUp" + suffix));
    ctx.beginPath();
    ctx.arc(ix, iy, 9, 0, 2 * Math.PI);
    ctx.fillStyle = COLORS.iris;
    ctx.fill();
    ctx.beginPath();
    ctx.arc(ix, iy, 4.2, 0, 2 * Math.PI);
    ctx.fillStyle = COLORS.pupil;
    ctx.fill();
    ctx.beginPath();
    ctx.arc(ix + 3, iy - 3, 1.8, 0, 2 * Math.PI);
    ctx.fillStyle = "#ffffff";
    ctx.fill();
    ctx.restore();
    // upper lid with lashes, lower lid
    ctx.beginPath();
    ctx.moveTo(xi - side * 1, y + 1);
    ctx.quadraticCurveTo(x - side * 4, top, xo + side * 2, y - 2);
    ctx.strokeStyle = COLORS.lash;
    ctx.lineWidth = 3;
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(xi, y + 2);
    ctx.quadraticCurveTo(x, bottom + 1, xo, y);
    ctx.strokeStyle = COLORS.skinLine;
    ctx.lineWidth = 1.2;
    ctx.stroke();
    // lid crease
    ctx.beginPath();
    ctx.moveTo(xi + side * 3, y - 10);
    ctx.quadraticCurveTo(x - side * 2, y - 22 + 6 * blink, xo - side * 1, y - 9);
    ctx.strokeStyle = "rgba(150, 88, 62, 0.35)";
    ctx.lineWidth = 1.4;
    ctx.stroke();
  }

  function drawNose(ctx, w) {
    var sneerL = weight(w, "noseSneerLeft"), sneerR = weight(w, "noseSneerRight");
    ctx.strokeStyle = COLORS.skinLine;
    ctx.lineWidth = 2;
    // bridge shadow on one side, nose tip and wings
    ctx.beginPath();
    ctx.moveTo(CX - 12, 205);
    ctx.quadraticCurveTo(CX - 16, 236, CX - 18, 252);
    ctx.strokeStyle = "rgba(150, 88, 62, 0.3)";
    ctx.stroke();
    ctx.strokeStyle = COLORS.skinLine;
    for (var side = -1; side <= 1; side += 2) {
      var lift = 3 * (side < 0 ? sneerR : sneerL);
      ctx.beginPath();
      ctx.moveTo(CX + side * 9, 271 - lift);
      ctx.quadraticCurveTo(CX + side * 25, 276 - lift, CX + side * 24, 262 - lift);
      ctx.quadraticCurveTo(CX + side * 22, 252 - lift, CX + side * 15, 254 - lift);
      ctx.stroke();
      ctx.beginPath();
      ctx.ellipse(CX + side * 10, 268 - lift, 5, 2.6, side * 0.3, 0, 2 * Math.PI);
      ctx.fillStyle = "rgba(110, 55, 40, 0.55)";
      ctx.fill();
    }
    ctx.beginPath();
    ctx.moveTo(CX - 8, 272);
    ctx.quadraticCurveTo(CX, 276, CX + 8, 272);
    ctx.stroke();
  }

  function drawFolds(ctx, m) {
    // nasolabial folds (deepen with a smile) and the philtrum
    for (var k = 0; k < 2; k++) {
      var c = m.corners[k], side = k === 0 ? -1 : 1;
      ctx.beginPath();
      ctx.moveTo(CX + side * 27, 268);
      ctx.quadraticCurveTo(CX + side * (52 + 6 * c.smile), 286, c.x + side * 10, c.y + 10);
      ctx.strokeStyle = "rgba(150, 88, 62, " + (0.14 + 0.22 * c.smile).toFixed(3) + ")";
      ctx.lineWidth = 1.8;
      ctx.stroke();
    }
    var top = m.upperOuter[(SAMPLES - 1) / 2];
    ctx.beginPath();
    ctx.moveTo(CX - 5, 280);
    ctx.quadraticCurveTo(CX - 7, 0.5 * (280 + top), CX - 8, top - 2);
    ctx.moveTo(CX + 5, 280);
    ctx.quadraticCurveTo(CX + 7, 0.5 * (280 + top), CX + 8, top - 2);
    ctx.strokeStyle = "rgba(150, 88, 62, 0.14)";
    ctx.lineWidth = 1.5;
    ctx.stroke();
  }

  function openingPath(ctx, m) {
    ctx.beginPath();
    path(ctx, m.x, m.upperInner, false, true);
    path(ctx, m.x, m.lowerInner, true, false);
    ctx.closePath();
  }

  function teethRow(ctx, edges, top, edgeY, dx, drop, front) {
    // edges: x offsets of tooth boundaries from the centre outwards; drawn from the back teeth in
    for (var k = edges.length - 2; k >= 0; k--) {
      for (var side = -1; side <= 1; side += 2) {
        var x0 = CX + dx + side * edges[k], x1 = CX + dx + side * edges[k + 1];
        var off = 0.5 * (edges[k] + edges[k + 1]);
        var edge = edgeY + drop * 0.0045 * off * off, r = 2.5;
        var y0 = Math.min(top, edge), y1 = Math.max(top, edge);
        ctx.beginPath();
        if (front) {           // upper teeth: rounded at the bottom edge
          ctx.moveTo(x0, y0);
          ctx.lineTo(x0, y1 - r);
          ctx.quadraticCurveTo(x0, y1, x0 + side * r, y1);
          ctx.lineTo(x1 - side * r, y1);
          ctx.quadraticCurveTo(x1, y1, x1, y1 - r);
          ctx.lineTo(x1, y0);
        } else {               // lower teeth: rounded at the top edge
          ctx.moveTo(x0, y1);
          ctx.lineTo(x0, y0 + r);
          ctx.quadraticCurveTo(x0, y0, x0 + side * r, y0);
          ctx.lineTo(x1 - side * r, y0);
          ctx.quadraticCurveTo(x1, y0, x1, y0 + r);
          ctx.lineTo(x1, y1);
        }
        ctx.closePath();
        var shade = Math.round(255 - 9 * k);
        ctx.fillStyle = k === 0 ? COLORS.tooth : "rgb(" + shade + "," + (shade - 4) + "," + (shade - 14) + ")";
        ctx.fill();
        ctx.strokeStyle = COLORS.toothEdge;
        ctx.lineWidth = 0.9;
        ctx.stroke();
      }
    }
  }

  function drawUpperTeeth(ctx) {
    ctx.fillStyle = COLORS.gum;
    ctx.fillRect(CX - 48, MOUTH_Y - 34, 96, 22);
    teethRow(ctx, [0, 9, 16.5, 23.5, 30, 36, 42], MOUTH_Y - 14, UPPER_TEETH_EDGE, 0, -1, true);
  }

  function drawLowerTeeth(ctx, m) {
    var edge = MOUTH_Y - 1 + m.jawDrop - 2 * m.jawForward;
    ctx.fillStyle = COLORS.gum;
    ctx.fillRect(CX - 44 + m.jawShift, edge + 12, 88, 30);
    teethRow(ctx, [0, 6.5, 13, 19.5, 26, 32, 38], edge + 14, edge, m.jawShift, 1, false);
  }

  function drawTongue(ctx, m) {
    var t = m.tongue, x = t.x, top = t.top, back = m.tongueBack;
    if (m.bodyRaise > 0.01) {   // the body, behind the front part: a broad hump up to the palate
      var body = t.bodyY, bw = t.bodyHalfWidth;
      ctx.beginPath();
      ctx.moveTo(x - bw, top + 14);
      ctx.bezierCurveTo(x - bw, body + 2, x - 0.6 * bw, body, x, body);
      ctx.bezierCurveTo(x + 0.6 * bw, body, x + bw, body + 2, x + bw, top + 14);
      ctx.closePath();
      ctx.fillStyle = COLORS.tongueBody;
      ctx.fill();
    }
    var ry = 16 * (1 - 0.2 * back);
    ctx.beginPath();
    ctx.ellipse(x, top + ry, t.halfWidth, ry, 0, 0, 2 * Math.PI);
    ctx.fillStyle = COLORS.tongue;
    ctx.fill();
    if (m.tipRaise > 0.01) {
      var tip = t.tipY;
      ctx.beginPath();
      ctx.moveTo(x - 15, top + 12);
      ctx.bezierCurveTo(x - 14, tip + 6, x - 8, tip, x, tip);
      ctx.bezierCurveTo(x + 8, tip, x + 14, tip + 6, x + 15, top + 12);
      ctx.closePath();
      ctx.fillStyle = COLORS.tongue;
      ctx.fill();
    }
    ctx.beginPath();
    ctx.moveTo(x, top + 6);
    ctx.lineTo(x, top + 18);
    ctx.strokeStyle = COLORS.tongueDark;
    ctx.lineWidth = 1.5;
    ctx.stroke();
  }

  function drawTongueOut(ctx, m) {
    var mid = (SAMPLES - 1) / 2, x = CX + m.jawShift, t = m.tongueOut;
    var top = m.upperInner[mid] + 2, bottom = m.lowerInner[mid] + 6 + 22 * t;
    var half = Math.min(0.6 * (m.x[SAMPLES - 1] - m.x[0]) / 2, 18 + 4 * t);
    ctx.beginPath();
    ctx.moveTo(x - half * 0.9, top);
    ctx.bezierCurveTo(x - half * 1.05, top + 0.5 * (bottom - top), x - half, bottom, x, bottom);
    ctx.bezierCurveTo(x + half, bottom, x + half * 1.05, top + 0.5 * (bottom - top), x + half * 0.9, top);
    ctx.closePath();
    var grad = ctx.createLinearGradient(0, top, 0, bottom);
    grad.addColorStop(0, COLORS.tongueDark);
    grad.addColorStop(0.35, COLORS.tongue);
    grad.addColorStop(1, COLORS.tongue);
    ctx.fillStyle = grad;
    ctx.fill();
    ctx.strokeStyle = "rgba(130, 40, 50, 0.6)";
    ctx.lineWidth = 1;
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x, top + 6);
    ctx.quadraticCurveTo(x + 0.5, 0.5 * (top + bottom), x, bottom - 7);
    ctx.strokeStyle = "rgba(130, 40, 50, 0.45)";
    ctx.stroke();
  }

  function drawMouth(ctx, m) {
    var mid = (SAMPLES - 1) / 2;
    if (m.opening > 0.05) {
      ctx.save();
      openingPath(ctx, m);
      ctx.clip();
      var grad = ctx.createRadialGradient(CX, m.upperInner[mid], 2, CX, m.upperInner[mid], 60);
      grad.addColorStop(0, COLORS.cavityDeep);
      grad.addColorStop(1, COLORS.cavity);
      ctx.fillStyle = grad;
      ctx.fillRect(CX - 90, MOUTH_Y - 60, 180, 160);
      drawTongue(ctx, m);
      if (m.jawForward > 0.5) {
        drawUpperTeeth(ctx);
        drawLowerTeeth(ctx, m);
      } else {
        drawLowerTeeth(ctx, m);
        drawUpperTeeth(ctx);
      }
      ctx.restore();
    }
    // lower lip
    ctx.beginPath();
    path(ctx, m.x, m.lowerInner, false, true);
    path(ctx, m.xOuter, m.lowerOuter, true, false);
    ctx.closePath();
    var yLow = m.lowerInner[mid], yLowOut = m.lowerOuter[mid];
    var grad2 = ctx.createLinearGradient(0, yLow, 0, yLowOut);
    grad2.addColorStop(0, m.rollLower > 0.3 ? COLORS.lipUpper : COLORS.lipLower);
    grad2.addColorStop(0.45, COLORS.lipLower);
    grad2.addColorStop(1, COLORS.lipUpper);
    ctx.fillStyle = grad2;
    ctx.fill();
    ctx.beginPath();
    ctx.ellipse(CX + 0.3 * (m.x[0] + m.x[SAMPLES - 1] - 2 * CX), 0.4 * yLow + 0.6 * yLowOut - 1,
      0.28 * (m.x[SAMPLES - 1] - m.x[0]) / 2, Math.max(0.5, 0.18 * (yLowOut - yLow)), 0, 0, 2 * Math.PI);
    ctx.fillStyle = "rgba(255, 225, 225, 0.25)";
    ctx.fill();
    ctx.lineWidth = 1;
    ctx.strokeStyle = "rgba(120, 45, 50, 0.45)";
    ctx.beginPath();
    path(ctx, m.xOuter, m.lowerOuter, false, true);
    ctx.stroke();
    if (m.opening > 0.05) {
      ctx.strokeStyle = COLORS.lipLine;
      ctx.lineWidth = 1.2;
      ctx.beginPath();
      path(ctx, m.x, m.lowerInner, false, true);
      ctx.stroke();
    }
    if (m.tongueOut > 0.02) {
      ctx.save();
      ctx.beginPath();
      ctx.rect(0, m.upperInner[mid] + 1, WIDTH, HEIGHT);
      ctx.clip();
      drawTongueOut(ctx, m);
      ctx.restore();
      ctx.save();
      openingPath(ctx, m);
      ctx.clip();
      drawUpperTeeth(ctx);
      ctx.restore();
    }
    // upper lip, then the inner lip line (a single line where the lips meet)
    ctx.beginPath();
    path(ctx, m.xOuter, m.upperOuter, false, true);
    path(ctx, m.x, m.upperInner, true, false);
    ctx.closePath();
    ctx.fillStyle = COLORS.lipUpper;
    ctx.fill();
    ctx.lineWidth = 1;
    ctx.strokeStyle = "rgba(120, 45, 50, 0.45)";
    ctx.beginPath();
    path(ctx, m.xOuter, m.upperOuter, false, true);
    ctx.stroke();
    ctx.strokeStyle = COLORS.lipLine;
    ctx.lineWidth = m.opening > 0.05 ? 1.2 : 2;
    ctx.beginPath();
    path(ctx, m.x, m.upperInner, false, true);
    ctx.stroke();
  }

  root.VispeechFace2D = { Face2D: Face2D, mouthShape: mouthShape, CHANNELS: CHANNELS };
})(typeof window !== "undefined" ? window : globalThis);
