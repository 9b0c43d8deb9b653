/* Material's search runs in a web worker, and browsers refuse to start a worker from a page
   opened from the file system. There, this runs the worker's script in a hidden frame with
   the worker's globals (postMessage, the "message" event, importScripts) bridged to the page,
   so that search works offline too. Its name keeps the offline plugin from adding a shim
   from the network. */
(function () {
  if (location.protocol !== "file:") return;
  window.Worker = class FrameWorker extends EventTarget {
    constructor(url) {
      super();
      const frame = document.createElement("iframe");
      frame.style.display = "none";
      (document.body || document.documentElement).appendChild(frame);
      const inner = frame.contentWindow;
      inner.postMessage = (data) =>
        setTimeout(() => this.dispatchEvent(new MessageEvent("message", { data })));
      inner.importScripts = (...urls) => Promise.all(urls.map((src) =>
        new Promise((loaded, failed) => {
          const script = inner.document.createElement("script");
          script.src = new URL(src, location.href).href;
          script.onload = loaded;
          script.onerror = failed;
          inner.document.head.appendChild(script);
        })));
      this.inner = inner;
      this.ready = inner.importScripts(url);
    }
    postMessage(data) {
      this.ready.then(() =>
        this.inner.dispatchEvent(new this.inner.MessageEvent("message", { data })));
    }
    terminate() {}
  };
})();
