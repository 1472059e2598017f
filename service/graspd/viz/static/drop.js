"use strict";
(function () {
const postUrl = document.body.dataset.post;
const drop = document.getElementById("drop"), status = document.getElementById("status");
const warnList = document.getElementById("warnings"), token = document.getElementById("token");
function say(text) { status.textContent = text; }
function showWarnings(list) {
  warnList.replaceChildren();
  for (const w of list) {
    const li = document.createElement("li");
    li.textContent = "warning " + String(w.code) + ": " + String(w.message);
    warnList.appendChild(li);
  }
}
const view = document.getElementById("view");
let lastFile = null;
async function send(file, target) {
  const picked = Number.isInteger(target) && target >= 0;
  say("detecting grasps in " + file.name + (picked ? " on object " + target : "") + " ...");
  showWarnings([]);
  lastFile = file;
  const form = new FormData();
  form.append("file", file, file.name);
  const headers = {};
  if (token.value) headers["Authorization"] = "Bearer " + token.value;
  const url = new URL(postUrl, window.location.href);
  if (picked) url.searchParams.set("target_object", String(target));
  try {
    const reply = await fetch(url.toString(), { method: "POST", body: form, headers: headers, credentials: "omit",
                                                referrerPolicy: "no-referrer" });
    const text = await reply.text();
    if (!reply.ok) {
      let why = text.slice(0, 400);
      try {
        const e = JSON.parse(text);
        why = e.error + (e.field ? " (" + e.field + ")" : "");
      } catch (err) { /* not JSON: its text */ }
      say("error " + reply.status + ": " + why);
      return;
    }
    let warnings = [];
    try { warnings = JSON.parse(reply.headers.get("X-Graspd-Warnings") || "[]"); } catch (err) { warnings = []; }
    showWarnings(Array.isArray(warnings) ? warnings : []);
    // the answer is shown in a sandboxed frame: its own opaque origin, no access to this page or the token
    view.srcdoc = text;
    say(file.name + (picked ? ": object " + target : ""));
  } catch (err) { say("failed: " + err); }
}
drop.addEventListener("dragover", e => { e.preventDefault(); drop.classList.add("over"); });
drop.addEventListener("dragleave", () => drop.classList.remove("over"));
drop.addEventListener("drop", e => {
  e.preventDefault(); drop.classList.remove("over");
  if (e.dataTransfer.files.length) send(e.dataTransfer.files[0]);
});
document.getElementById("pick").addEventListener("change", e => {
  if (e.target.files.length) send(e.target.files[0]);
});
// the view in the frame picked an object (or every object: -1): send the same file again with that target
window.addEventListener("message", e => {
  if (e.source !== view.contentWindow || !lastFile || !e.data || typeof e.data !== "object") return;
  const k = e.data.graspdTarget;
  if (!Number.isInteger(k) || k < -1 || k > 100000) return;
  send(lastFile, k);
});
document.body.setAttribute("data-ready", "1");
})();
