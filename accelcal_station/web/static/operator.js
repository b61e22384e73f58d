// The operator page: polls the station's state, draws the pose and the live level, sends the
// operator's answers (buttons or keys).  Every text from the station is set with textContent.
(function () {
  "use strict";
  var NS = "http://www.w3.org/2000/svg";
  var $ = function (id) { return document.getElementById(id); };
  var shownPose = null, phase = "", busy = false, done = false;
  var KEYS = {Enter: "accept", r: "replace", R: "replace", s: "skip", S: "skip", a: "abort", A: "abort"};

  function el(tag, attrs, text) {
    var e = document.createElementNS(NS, tag);
    Object.keys(attrs).forEach(function (k) { e.setAttribute(k, attrs[k]); });
    if (text !== undefined) { e.textContent = text; }
    return e;
  }

  function drawBoard(pic) {
    var svg = $("board");
    var parts = [];
    parts.push(el("line", {"class": "ground", x1: 10, x2: pic.size - 50, y1: pic.ground_y, y2: pic.ground_y}));
    var arrows = pic.arrows.filter(function (a) { return !a.front; })
      .concat(["FACES"], pic.arrows.filter(function (a) { return a.front; }));
    arrows.forEach(function (a) {
      if (a === "FACES") {
        pic.faces.forEach(function (f) {
          // the component side is +z: it faces the sky when the board lies flat reading z +1 g
          var kind = f.face === "z+" ? "top" : (f.face === "z-" ? "bottom" : "edge");
          parts.push(el("polygon", {"class": "face " + kind, points: f.points, "fill-opacity": f.shade}));
        });
        return;
      }
      parts.push(el("line", {"class": "arrow " + a.axis + (a.front ? "" : " back"),
        x1: a.x1, y1: a.y1, x2: a.x2, y2: a.y2}));
      parts.push(el("text", {"class": "albl " + a.axis, x: a.x2 + (a.x2 >= a.x1 ? 6 : -20), y: a.y2 + 7},
        "+" + a.axis));
    });
    var g = pic.gravity;
    parts.push(el("line", {"class": "grav", x1: g.x1, y1: g.y1, x2: g.x2, y2: g.y2}));
    parts.push(el("polygon", {"class": "grav", points: (g.x2 - 8) + "," + (g.y2 - 10) + " " + (g.x2 + 8) + "," +
      (g.y2 - 10) + " " + g.x2 + "," + (g.y2 + 4)}));
    parts.push(el("text", {"class": "glbl", x: g.x1 - 6, y: g.y1 - 10}, "g"));
    svg.replaceChildren.apply(svg, parts);
  }

  function setButtons(on) {
    ["b-accept", "b-replace", "b-skip", "b-abort"].forEach(function (id) { $(id).disabled = !on; });
  }

  function showLevel(lv) {
    if (!lv) { $("ready").textContent = "–"; $("ready").className = "ready"; return; }
    $("off").textContent = lv.off_deg.toFixed(1) + "°";
    $("still").textContent = lv.still ? "STILL" : "MOVING";
    $("face").textContent = lv.direction_ok ? "right face" : "on " + lv.face;
    var b = $("bubble");
    b.setAttribute("cx", (lv.bubble[0] * 90).toFixed(1));
    b.setAttribute("cy", (-lv.bubble[1] * 90).toFixed(1));
    b.setAttribute("class", "bubble" + (lv.ready ? " ok" : ""));
    $("ready").textContent = lv.ready ? "READY — press Accept" : (lv.direction_ok ? "hold still…" : "WRONG FACE — turn the board");
    $("ready").className = "ready " + (lv.ready ? "ok" : "bad");
  }

  function showResult(r) {
    var box = $("result");
    box.className = "result " + r.verdict.toLowerCase();
    $("result-verdict").textContent = r.verdict;
    $("result-board").textContent = (r.serial ? "board " + r.serial : "") + (r.run_id ? " · run " + r.run_id : "");
    var items = r.reasons.map(function (x) { var li = document.createElement("li"); li.textContent = x.message; return li; });
    $("result-reasons").replaceChildren.apply($("result-reasons"), items);
    var f = r.figures || {};
    var bits = [];
    if (f.residual_rms_mg !== undefined) { bits.push("fit residual " + f.residual_rms_mg.toFixed(3) + " mg"); }
    if (f.verify_error_max_mg !== undefined && f.verify_error_max_mg !== null) { bits.push("verify " + f.verify_error_max_mg.toFixed(3) + " mg"); }
    if (f.nvm) { bits.push("NVM " + f.nvm); }
    $("result-figures").textContent = bits.join(" · ");
    box.hidden = false;
  }

  function render(s) {
    phase = s.phase;
    var total = s.total || 1, n = s.pose ? s.pose.number : 0;
    $("progress-bar").style.width = Math.min(100, 100 * Math.max(0, n - (phase === "ask" || phase === "place" ? 1 : 0)) / total) + "%";
    $("progress-text").textContent = s.pose ? "pose " + Math.min(n, total) + " of " + total : phase;
    if (s.pose && shownPose !== s.pose.number) {
      shownPose = s.pose.number;
      $("pose-number").textContent = "Pose " + s.pose.number + " · " + s.pose.name;
      $("instruction").textContent = "Put the board " + s.pose.words.split(" (")[0];
      $("angles").textContent = "pitch " + s.pose.pitch_deg.toFixed(1) + "°, roll " + s.pose.roll_deg.toFixed(1) +
        "° · expects x " + s.pose.expects_g[0].toFixed(3) + "  y " + s.pose.expects_g[1].toFixed(3) + "  z " + s.pose.expects_g[2].toFixed(3) + " g";
      drawBoard(s.pose.picture);
    }
    setButtons(phase === "ask");
    showLevel(phase === "ask" ? s.level : null);
    var cap = s.capture;
    $("capture").hidden = !cap;
    if (cap) { $("capture-label").textContent = cap.label; $("capture-bar").style.width = (100 * cap.fraction) + "%"; }
    var form = $("serial-form");
    if (phase === "serial" && form.hidden) { form.hidden = false; $("serial-question").textContent = s.question; $("serial-input").focus(); }
    if (phase !== "serial") { form.hidden = true; }
    var log = s.lines.map(function (t) { var li = document.createElement("li"); li.textContent = t; return li; });
    $("log").replaceChildren.apply($("log"), log);
    if (phase === "done" && s.result) { done = true; showResult(s.result); }
  }

  function send(body) {
    if (busy) { return; }
    busy = true;
    setButtons(false);
    fetch("/operator/answer", {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body)})
      .finally(function () { busy = false; poll(); });
  }

  function poll() {
    fetch("/operator/state", {cache: "no-store"}).then(function (r) { return r.json(); })
      .then(render).catch(function () { $("progress-text").textContent = "station not answering"; });
  }

  document.querySelectorAll(".buttons button").forEach(function (b) {
    b.addEventListener("click", function () { send({answer: b.dataset.answer}); });
  });
  document.addEventListener("keydown", function (e) {
    if (phase !== "ask" || e.target.tagName === "INPUT" || !KEYS[e.key]) { return; }
    e.preventDefault();
    send({answer: KEYS[e.key]});
  });
  $("serial-form").addEventListener("submit", function (e) {
    e.preventDefault();
    send({answer: "serial", serial: $("serial-input").value});
    $("serial-input").value = "";
  });
  (function loop() { if (!done) { poll(); window.setTimeout(loop, 250); } }());
}());
