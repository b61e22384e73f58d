// The line page, live: a server-sent event per finished run triggers one refresh of the
// page body (rendered and escaped by the server); without EventSource it polls every 2 s.
(function () {
  "use strict";
  var body = document.getElementById("line-body");
  var note = document.getElementById("live");
  var pending = false;

  function say(text, ok) {
    note.textContent = text;
    note.className = "live-note " + (ok ? "ok" : "stale");
  }

  function refresh() {
    if (pending) { return; }
    pending = true;
    window.setTimeout(function () {
      fetch(note.dataset.refresh, {cache: "no-store"}).then(function (r) {
        if (!r.ok) { throw new Error("HTTP " + r.status); }
        return r.text();
      }).then(function (html) {
        // the server's own template output (autoescaped); parsed inert, then moved in
        var doc = new DOMParser().parseFromString(html, "text/html");
        body.replaceChildren.apply(body, Array.prototype.slice.call(doc.body.childNodes));
        say("live · updated " + new Date().toISOString().slice(11, 19) + " UTC", true);
      }).catch(function (e) {
        say("live · refresh failed (" + e.message + "), retrying", false);
      }).finally(function () { pending = false; });
    }, 150);
  }

  function listen(cursor) {
    var es = new EventSource(note.dataset.events + "?after=" + encodeURIComponent(cursor));
    es.addEventListener("run", refresh);
    es.onopen = function () { say("live", true); };
    es.onerror = function () { say("live · reconnecting", false); };
  }

  if (window.EventSource) {
    fetch("/api/v1/events/head", {cache: "no-store"}).then(function (r) { return r.json(); })
      .then(function (h) { listen(h.next); refresh(); })
      .catch(function () { window.setInterval(refresh, 2000); });
  } else {
    window.setInterval(refresh, 2000);
  }
}());
