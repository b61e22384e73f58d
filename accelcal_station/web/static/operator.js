// The operator page: polls the station's state, draws the pose and the live level, sends the
// operator's answers (buttons or keys).  Every text from the station is set with textContent.
(function () {
  "use strict";
  var NS = "http://www.w3.org/2000/svg";
  var $ = function (id) { return document.getElementById(id); };
  var shownPose = null, phase = "", busy = false, done = false, misses = 0;
  // the operator's language: the station's catalog for this page's texts (web/operator_text.py)
  var TEXT = JSON.parse(document.getElementById("i18n").textContent);
  function T(msgid, args) {
    var out = TEXT[msgid] || msgid;
    Object.keys(args || {}).forEach(function (k) { out = out.split("{" + k + "}").join(String(args[k])); });
    return out;
  }
  // numbers as the operator's language writes them (German: a decimal comma), fixed digits
  var LANG = document.documentElement.lang || "en";
  function num(x, digits) {
    return Number(x).toLocaleString(LANG, {minimumFractionDigits: digits, maximumFractionDigits: digits});
  }
  var KEYS = {Enter: "accept", r: "replace", R: "replace", s: "skip", S: "skip", a: "abort", A: "abort"};

  function el(tag, attrs, text) {
    var e = document.createElementNS(NS, tag);
    Object.keys(attrs).forEach(function (k) { e.setAttribute(k, attrs[k]); });
    if (text !== undefined) { e.textContent = text; }
    return e;
  }

  function drawBoard(pic, svg) {
    svg = svg || $("board");
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
    if (!lv) {
      $("ready").textContent = "–"; $("ready").className = "ready";
      $("still").textContent = "–"; $("off").textContent = "–"; $("face").textContent = "–";
      return;
    }
    $("off").textContent = num(lv.off_deg, 1) + "°";
    $("still").textContent = lv.still ? T("STILL") : T("MOVING");
    $("face").textContent = lv.direction_ok ? T("right face") : T("on {face}", {face: lv.face});
    var b = $("bubble");
    b.setAttribute("cx", (lv.bubble[0] * 90).toFixed(1));
    b.setAttribute("cy", (-lv.bubble[1] * 90).toFixed(1));
    b.setAttribute("class", "bubble" + (lv.ready ? " ok" : ""));
    $("ready").textContent = lv.ready ? T("READY — press Accept") : (lv.direction_ok ? T("hold still…") : T("WRONG FACE — turn the board"));
    $("ready").className = "ready " + (lv.ready ? "ok" : "bad");
  }

  function showResult(r) {
    var box = $("result");
    box.className = "result " + r.verdict.toLowerCase();
    $("result-verdict").textContent = T(r.verdict);
    $("result-board").textContent = (r.serial ? T("board {serial}", {serial: r.serial}) : "") +
      (r.run_id ? " · " + T("run {id}", {id: r.run_id}) : "");
    var items = r.reasons.map(function (x) {  // the operator's words for the reason, then its figures
      var li = document.createElement("li"); li.textContent = (x.title ? x.title + ": " : "") + x.message; return li;
    });
    $("result-reasons").replaceChildren.apply($("result-reasons"), items);
    var f = r.figures || {};
    var bits = [];
    if (f.residual_rms_mg !== undefined) { bits.push(T("fit residual {mg} mg", {mg: num(f.residual_rms_mg, 3)})); }
    if (f.verify_error_max_mg !== undefined && f.verify_error_max_mg !== null) {
      bits.push(T("check after calibration {mg} mg", {mg: num(f.verify_error_max_mg, 3)}));
    }
    if (f.nvm) { bits.push(T("NVM {what}", {what: f.nvm})); }
    $("result-figures").textContent = bits.join(" · ");
    box.hidden = false;
  }

  function showSummary(s) {
    var box = $("result");
    box.className = "result shift";
    $("result-verdict").textContent = T("SHIFT OVER");
    var fpy = s.first_pass_yield === null ? "–" : num(100 * s.first_pass_yield, 1) + " %";
    var counts = {boards: s.boards, pass: s.pass, fail: s.fail, aborted: s.aborted, error: s.error, fpy: fpy};
    // the catalog's singular for one board
    $("result-board").textContent = s.boards === 1 ?
      T("{boards} board · PASS {pass} · FAIL {fail} · aborted {aborted} · error {error} · first-pass yield {fpy}", counts) :
      T("{boards} boards · PASS {pass} · FAIL {fail} · aborted {aborted} · error {error} · first-pass yield {fpy}", counts);
    var titles = s.reason_titles || {};
    var items = Object.keys(s.reasons_by_code).map(function (c) {
      var li = document.createElement("li"); li.textContent = (titles[c] || c || "–") + ": " + s.reasons_by_code[c]; return li;
    });
    $("result-reasons").replaceChildren.apply($("result-reasons"), items);
    $("result-figures").textContent = T("{start} to {end} (UTC)", {start: s.started_utc, end: s.ended_utc}) +
      " · " + T("ended by: {why}", {why: T(s.ended_by)});
    box.hidden = false;
  }

  // the design's poses as small pictures: done, current, to do; verification poses labelled
  var stripKey = "";
  function drawStrip(s) {
    var plan = s.plan || [], cur = s.pose ? s.pose.index : null;
    var finished = !s.pose && !!s.result;
    var key = plan.length + ":" + cur + ":" + finished;
    if (key === stripKey) { return; }
    stripKey = key;
    var items = plan.map(function (p, i) {
      var state = finished || (cur !== null && i < cur) ? "done" : (i === cur ? "current" : "todo");
      var li = document.createElement("li");
      li.className = "strip-item " + state + (p.verify ? " verify" : "");
      var svg = document.createElementNS(NS, "svg");
      svg.setAttribute("viewBox", "0 0 320 320");
      svg.setAttribute("class", "board mini");
      drawBoard(p.picture, svg);
      var cap = document.createElement("span");
      cap.textContent = (p.verify ? T("verify") + " · " : "") + p.name + (state === "done" ? " ✓" : "");
      li.replaceChildren(svg, cap);
      return li;
    });
    $("strip").replaceChildren.apply($("strip"), items);
  }

  function progressText(s) {
    var plan = s.plan || [];
    if (!s.pose || s.pose.index === null || s.pose.index === undefined) { return s.pose ? T("pose {n}", {n: s.pose.number}) : ""; }
    var design = plan.filter(function (p) { return !p.verify; }).length;
    if (s.pose.verify) { return T("verify {n} of {total}", {n: s.pose.index - design + 1, total: plan.length - design}); }
    return T("pose {n} of {total}", {n: s.pose.index + 1, total: design});
  }

  function render(s) {
    phase = s.phase;
    $("board-id").textContent = s.board ? T("Board {n}", {n: s.board.number}) + " · " + s.board.serial : "";
    if (!s.pose) { shownPose = null; }
    var total = (s.plan && s.plan.length) || s.total || 1;
    var n = s.pose ? (s.pose.index !== null && s.pose.index !== undefined ? s.pose.index + 1 : s.pose.number) : 0;
    $("progress-bar").style.width = Math.min(100, 100 * Math.max(0, n - (phase === "ask" || phase === "place" ? 1 : 0)) / total) + "%";
    $("progress-text").textContent = s.pose ? progressText(s) : (phase === "serial" ? T("next board") : T(phase));
    if (s.pose && shownPose !== s.pose.number) {
      shownPose = s.pose.number;
      $("pose-number").textContent = T("Pose {n}", {n: s.pose.number}) + " · " + s.pose.name;
      $("instruction").textContent = T("Put the board {words}", {words: s.pose.words.split(" (")[0]});
      var e = s.pose.expects_g;
      $("angles").textContent = T("pitch {pitch}°, roll {roll}° · expects x {x}  y {y}  z {z} g", {
        pitch: num(s.pose.pitch_deg, 1), roll: num(s.pose.roll_deg, 1), x: num(e[0], 3), y: num(e[1], 3),
        z: num(e[2], 3)});
      drawBoard(s.pose.picture);
    }
    drawStrip(s);
    setButtons(phase === "ask");
    showLevel(phase === "ask" ? s.level : null);
    var cap = s.capture;
    if (cap) {  // the level is not read while the station captures: say so, not a stale MOVING
      $("still").textContent = T("CAPTURING");
      $("ready").textContent = T("CAPTURING — hold still");
      $("ready").className = "ready capturing";
    }
    $("capture").hidden = !cap;
    if (cap) { $("capture-label").textContent = cap.label; $("capture-bar").style.width = (100 * cap.fraction) + "%"; }
    var form = $("serial-form");
    if (phase === "serial") {  // a barcode reader types into the focused field: keep it focused
      form.hidden = false;
      $("serial-question").textContent = s.question;
      $("b-end").hidden = !s.shift;
      if (document.activeElement !== $("serial-input")) { $("serial-input").focus(); }
    } else { form.hidden = true; }
    var log = s.lines.map(function (t) { var li = document.createElement("li"); li.textContent = t; return li; });
    $("log").replaceChildren.apply($("log"), log);
    // between boards what the station says to the operator (a refused scan, a device gone and back) is shown
    // over all; never over a verdict, a fault or the shift's end, which say it themselves
    var note = !s.pose && phase !== "done" && phase !== "shift_over" && phase !== "station_fault" ? (s.notice || "") : "";
    $("notice").hidden = !note;
    $("notice").textContent = note;
    $("b-end-fault").hidden = !(phase === "station_fault" && s.shift);
    // the station's verdict stays on every page until the station starts the next board
    if (phase === "shift_over" && s.summary) { showSummary(s.summary); } else if (s.result) { showResult(s.result); }
    else { $("result").hidden = true; }
    done = phase === "shift_over" || (!s.shift && phase === "done");
  }

  function send(body) {
    if (busy) { return; }
    busy = true;
    setButtons(false);
    fetch("/operator/answer", {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body)})
      .finally(function () { busy = false; poll(); });
  }

  function poll() {
    fetch("/operator/state", {cache: "no-store"}).then(function (r) {
      if (!r.ok) { throw new Error("HTTP " + r.status); }
      return r.json();
    }).then(function (s) { misses = 0; $("lost").hidden = true; render(s); })
      .catch(function () { misses += 1; if (misses >= 3) { $("lost").hidden = false; } });
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
    var v = $("serial-input").value.trim();
    $("serial-input").value = "";
    if (v) { send({answer: "serial", serial: v}); }  // a blank scan is ignored, as in the terminal
  });
  $("b-end").addEventListener("click", function () { send({answer: "end"}); });
  $("b-end-fault").addEventListener("click", function () { send({answer: "end"}); });
  // a page that lost the station keeps asking: it shows the station again as soon as it answers
  (function loop() { if (!done) { poll(); window.setTimeout(loop, 250); } }());
}());
