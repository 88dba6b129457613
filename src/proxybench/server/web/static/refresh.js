// Reload the page every 10 s while the "refresh" box is ticked (remembered in this browser).
(function () {
  var box = document.getElementById("auto-refresh");
  if (!box) return;
  var key = "proxybench.autoRefresh";
  box.checked = window.localStorage.getItem(key) === "1";
  var timer = null;
  function arm() {
    if (timer) window.clearTimeout(timer);
    timer = box.checked ? window.setTimeout(function () { window.location.reload(); }, 10000) : null;
  }
  box.addEventListener("change", function () { window.localStorage.setItem(key, box.checked ? "1" : "0"); arm(); });
  arm();
})();
