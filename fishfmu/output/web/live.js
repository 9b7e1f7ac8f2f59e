// fishfmu serve --live: asks the server for the line's latest frame rate_hz times a second and hands it to the
// page (replay.js, applyFrame).  Only in the live page: a recorded replay needs nothing from the network.  Read-only:
// it only ever GETs the frame.
"use strict";
window.ReplayLive = {
  follow(api, live) {
    const period_ms = 1000 / live.rate_hz;
    (async function poll() {
      for (;;) {
        const started = performance.now();
        try {
          const r = await fetch(live.frame, { cache: "no-store" });
          if (!r.ok) throw new Error(`HTTP ${r.status}`);
          api.applyFrame(await r.json());
        } catch (err) {
          api.lost(err.message || String(err));   // the run ended and the server with it, or it is unreachable
        }
        await new Promise((done) => setTimeout(done, Math.max(0, period_ms - (performance.now() - started))));
      }
    })();
  },
};
