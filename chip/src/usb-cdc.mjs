// The USB host side of a CDC-ACM serial port, on top of rp2040js's USBCDC.
//
// rp2040js 1.4.1 answers every OUT transfer the device arms at once, with zero bytes when the host
// has nothing to send, so an idle MicroPython takes a USB interrupt about every 10 us. A real host
// NAKs OUT tokens until it has data: the armed buffer stays armed and the device sees a BUFF_STATUS
// interrupt only when bytes arrive. That is what this class does. Host-to-device bytes wait in an
// unbounded queue (the host's own buffer) and go out in packets of at most the armed length.
import { USBCDC } from 'rp2040js';

export class HostCDC extends USBCDC {
  constructor(usb) {
    super(usb);
    this.hostQueue = []; // Uint8Array chunks; the first one is consumed from hostOffset
    this.hostOffset = 0;
    this.pendingHostBytes = 0; // bytes the host has queued that the device has not taken yet
    this.armedLength = 0; // length of the OUT buffer the device has armed and we NAK; 0 if none
    this.flushAlarm = usb.rp2040.clock.createAlarm(() => {
      this.flushAlarm.scheduled = false;
      this.serveOut();
    });
    usb.onEndpointRead = (endpoint, size) => {
      if (endpoint !== this.outEndpoint) return;
      this.armedLength = size;
      this.serveOut();
    };
  }

  /** Queues bytes from the host; they reach the device in its next OUT transfers. */
  sendSerialBytes(bytes) {
    if (!bytes.length) return;
    this.hostQueue.push(Uint8Array.from(bytes));
    this.pendingHostBytes += bytes.length;
    // Complete on the clock, not inside the caller: several calls in a row make one packet.
    if (this.armedLength && !this.flushAlarm.scheduled) this.flushAlarm.schedule(0);
  }

  sendSerialByte(byte) {
    this.sendSerialBytes([byte]);
  }

  serveOut() {
    if (!this.armedLength || !this.pendingHostBytes) return; // NAK
    const packet = new Uint8Array(Math.min(this.armedLength, this.pendingHostBytes));
    for (let filled = 0; filled < packet.length;) {
      const chunk = this.hostQueue[0];
      const take = Math.min(chunk.length - this.hostOffset, packet.length - filled);
      packet.set(chunk.subarray(this.hostOffset, this.hostOffset + take), filled);
      filled += take;
      this.hostOffset += take;
      if (this.hostOffset === chunk.length) {
        this.hostQueue.shift();
        this.hostOffset = 0;
      }
    }
    this.pendingHostBytes -= packet.length;
    this.armedLength = 0;
    this.usb.endpointReadDone(this.outEndpoint, packet);
  }
}
