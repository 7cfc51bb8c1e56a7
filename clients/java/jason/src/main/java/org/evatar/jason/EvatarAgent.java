package org.evatar.jason;

import jason.architecture.AgArch;
import jason.asSemantics.ActionExec;
import jason.asSemantics.Agent;
import jason.asSemantics.Message;
import jason.asSemantics.TransitionSystem;
import jason.asSyntax.ASSyntax;
import jason.asSyntax.ListTerm;
import jason.asSyntax.ListTermImpl;
import jason.asSyntax.Literal;
import jason.asSyntax.NumberTerm;
import jason.asSyntax.StringTerm;
import jason.asSyntax.Structure;
import jason.asSyntax.Term;
import java.io.IOException;
import java.nio.file.Files;
import java.nio.file.Path;
import java.time.Duration;
import java.util.ArrayList;
import java.util.Collection;
import java.util.List;
import java.util.Map;
import java.util.concurrent.ConcurrentHashMap;
import java.util.concurrent.ConcurrentLinkedQueue;
import java.util.concurrent.CopyOnWriteArrayList;
import org.evatar.client.ActuatorEmulator;
import org.evatar.client.Control;
import org.evatar.client.Description;
import org.evatar.client.EvatarClient;
import org.evatar.client.Param;
import org.evatar.client.Signal;

/**
 * A Jason agent embodied through EVATAR: its body is a BIL description of
 * emulators (the VA's side of a pairing), its actions become BIL requests and
 * the signals it receives become percepts.
 *
 * <p>Percepts (strings are Jason strings, parameters {@code param(Name, Value)}):
 * <ul>
 * <li>{@code emulator(Component, Category, Type, Params)}: every {@code Consumes} entry of the body
 *     (what the agent can ask for);</li>
 * <li>{@code bound(Component, Type, Provider)} and {@code embodied}: from EVATAR's last Binding;
 *     {@code unbound(Component, Type, Reason)};</li>
 * <li>{@code sensor(Component, Type, Params, Time)}: sensor data or an event for one of its
 *     emulators (present for one reasoning cycle: handle {@code +sensor(...)});</li>
 * <li>{@code feedback(Tag, Type, Result, Params)}: the answer to the request tagged {@code Tag};
 *     Result is {@code ok}, {@code progress}, {@code timeout} or {@code failed(Code)} (one cycle);</li>
 * <li>{@code evatar_error(Code, Message)}: an error EVATAR sent that answers no request (one cycle).</li>
 * </ul>
 * Actions:
 * <ul>
 * <li>{@code request(Tag, Type, Filter, Params)}: sends a request awaiting feedback from the emulator
 *     that consumes {@code Type} and whose entry has every {@code param(N, V)} of {@code Filter}, to
 *     the provider EVATAR bound to it. It succeeds once sent; the answer arrives as
 *     {@code feedback(Tag, ...)}. It fails when no emulator matches or it is not bound.</li>
 * </ul>
 */
public class EvatarAgent extends AgArch {
    private final EvatarClient.Options options;
    private final Description body;
    private final String aslSource;
    private final String aslName;
    private final String name;
    private final ConcurrentLinkedQueue<Literal> events = new ConcurrentLinkedQueue<>();
    private final Map<String, Term> tags = new ConcurrentHashMap<>();
    private final Map<String, String> types = new ConcurrentHashMap<>();
    private final List<String> actionLog = new CopyOnWriteArrayList<>();
    private final Object sleep = new Object();
    private volatile List<Literal> state = List.of();
    private volatile boolean running;
    private volatile EvatarClient client;
    private Thread thread;

    /**
     * @param options where and how to connect (role agent); its entity id must be the body's
     * @param body    the VA's description (its emulators)
     * @param asl     the AgentSpeak program's text
     * @param aslName a name for the program in Jason's messages
     */
    public EvatarAgent(EvatarClient.Options options, Description body, String asl, String aslName) {
        this.options = options;
        this.body = body;
        this.aslSource = asl;
        this.aslName = aslName;
        this.name = body.entityId();
    }

    /** Loads the program from a file. */
    public static EvatarAgent fromFile(EvatarClient.Options options, Description body, Path asl) throws IOException {
        return new EvatarAgent(options, body, Files.readString(asl), asl.getFileName().toString());
    }

    /** Parses the program, connects over TCP, describes the body and starts reasoning. */
    public void start() throws Exception {
        start(false);
    }

    /** The same over this program's stdin/stdout (EVATAR's port connector started it). */
    public void startStdio() throws Exception {
        start(true);
    }

    private void start(boolean stdio) throws Exception {
        // No web mind inspector: it would listen on a fixed port.
        jason.util.Config.get().setProperty(jason.util.Config.START_WEB_MI, "false");
        Agent ag = new Agent();
        new TransitionSystem(ag, null, null, this);
        ag.initAg();
        ag.parseAS(new java.io.StringReader(aslSource), aslName);
        ag.addInitialBelsInBB();
        ag.addInitialGoalsInTS();
        refreshState(null);
        EvatarClient.Listener l = new EvatarClient.Listener() {
            @Override
            public void onSignal(Signal s) {
                perceiveSignal(s);
            }

            @Override
            public void onBinding(Control.Binding b) {
                refreshState(b);
            }

            @Override
            public void onClosed(String reason, Throwable cause) {
                events.add(ASSyntax.createLiteral("evatar_closed", ASSyntax.createString(reason)));
                wakeUp();
            }
        };
        client = stdio ? EvatarClient.connectStdio(options, l) : EvatarClient.connect(options, l);
        client.describe(body);
        running = true;
        thread = new Thread(this::loop, "jason-" + name);
        thread.setDaemon(true);
        thread.start();
    }

    /** The client, for inspection. */
    public EvatarClient client() {
        return client;
    }

    /** Every action the agent executed, as text, in order. */
    public List<String> actions() {
        return List.copyOf(actionLog);
    }

    /** True when the agent believes {@code literal} (for example {@code done}). */
    public boolean believes(String literal) {
        try {
            Literal lit = ASSyntax.parseLiteral(literal);
            synchronized (this) {
                return getTS().getAg().believes(lit, new jason.asSemantics.Unifier());
            }
        } catch (Exception e) {
            throw new IllegalArgumentException("not a literal: " + literal, e);
        }
    }

    /** Stops reasoning and leaves EVATAR. */
    @Override
    public void stop() {
        running = false;
        wakeUp();
        if (thread != null) {
            try {
                thread.join(5000);
            } catch (InterruptedException e) {
                Thread.currentThread().interrupt();
            }
        }
        if (client != null) {
            client.close();
        }
    }

    private void loop() {
        while (running) {
            synchronized (this) {
                getTS().reasoningCycle();
            }
            if (getTS().canSleep()) {
                synchronized (sleep) {
                    if (events.isEmpty() && running) {
                        try {
                            sleep.wait(50);
                        } catch (InterruptedException e) {
                            return;
                        }
                    }
                }
            }
        }
    }

    private void wakeUp() {
        synchronized (sleep) {
            sleep.notifyAll();
        }
    }

    @Override
    public void wake() {
        wakeUp();
    }

    // ------------------------------------------------------------------ perception

    private void refreshState(Control.Binding b) {
        List<Literal> s = new ArrayList<>();
        for (Description.Component c : body.components()) {
            for (Description.Service e : c.consumes()) {
                s.add(ASSyntax.createLiteral("emulator", ASSyntax.createString(c.id()),
                        ASSyntax.createString(e.category()), ASSyntax.createString(e.type()), params(e.parameters())));
            }
        }
        if (b != null) {
            boolean any = false;
            for (Control.Bound r : b.bound()) {
                if (r.consumerEntity().equals(name)) {
                    any = true;
                    s.add(ASSyntax.createLiteral("bound", ASSyntax.createString(r.consumerComponent()),
                            ASSyntax.createString(r.type()), ASSyntax.createString(r.providerComponent())));
                }
            }
            for (Control.Unbound u : b.unbound()) {
                if (u.consumerEntity().equals(name)) {
                    s.add(ASSyntax.createLiteral("unbound", ASSyntax.createString(u.consumerComponent()),
                            ASSyntax.createString(u.type()), ASSyntax.createString(u.reason())));
                }
            }
            if (any) {
                s.add(ASSyntax.createLiteral("embodied"));
            }
        }
        state = s;
        wakeUp();
    }

    private void perceiveSignal(Signal s) {
        String ctx = s.context();
        if (s.inReplyTo() != null && tags.containsKey(s.inReplyTo())) {
            String id = s.inReplyTo();
            Term tag = ctx.equals(Signal.PROGRESS) ? tags.get(id) : tags.remove(id);
            String type = ctx.equals(Signal.PROGRESS) ? types.get(id) : types.remove(id);
            events.add(ASSyntax.createLiteral("feedback", tag, ASSyntax.createString(type), result(s),
                    params(s.parameters())));
        } else if (ctx.equals(Signal.SENSOR_DATA) || ctx.equals(Signal.EVENT)) {
            events.add(ASSyntax.createLiteral("sensor", ASSyntax.createString(s.receiver()),
                    ASSyntax.createString(s.type()), params(s.parameters()), ASSyntax.createNumber(s.timestamp())));
        } else if (ctx.equals(Signal.ERROR)) {
            events.add(ASSyntax.createLiteral("evatar_error", ASSyntax.createString(s.type()),
                    ASSyntax.createString(s.param("Message").orElse(""))));
        }
        wakeUp();
    }

    /** Feedback comes through the request's future; its Progress through the listener. */
    private void answer(String id, Signal s, Throwable error) {
        Term tag = tags.remove(id);
        String type = types.remove(id);
        if (tag == null) {
            return;
        }
        Term r = error != null
                ? ASSyntax.createStructure("failed", ASSyntax.createString(String.valueOf(error.getMessage())))
                : result(s);
        events.add(ASSyntax.createLiteral("feedback", tag, ASSyntax.createString(type), r,
                error != null ? new ListTermImpl() : params(s.parameters())));
        wakeUp();
    }

    private static Term result(Signal s) {
        if (s.context().equals(Signal.PROGRESS)) {
            return ASSyntax.createAtom("progress");
        }
        if (s.isTimeout()) {
            return ASSyntax.createAtom("timeout");
        }
        if (s.isError() || "EVATAR".equals(s.category()) || "ERROR".equals(s.category())) {
            return ASSyntax.createStructure("failed", ASSyntax.createString(s.type()));
        }
        return ASSyntax.createAtom("ok");
    }

    private static ListTerm params(List<Param> ps) {
        ListTerm l = new ListTermImpl();
        ListTerm tail = l;
        for (Param p : ps) {
            tail = tail.append(ASSyntax.createStructure("param", ASSyntax.createString(p.name()),
                    ASSyntax.createString(p.value())));
        }
        return l;
    }

    @Override
    public Collection<Literal> perceive() {
        List<Literal> ps = new ArrayList<>(state);
        for (Literal e; (e = events.poll()) != null; ) {
            ps.add(e);
        }
        return ps;
    }

    // ------------------------------------------------------------------ action

    @Override
    public void act(ActionExec action) {
        Structure a = action.getActionTerm();
        actionLog.add(a.toString());
        try {
            if (a.getFunctor().equals("request") && a.getArity() == 4) {
                request(a.getTerm(0), text(a.getTerm(1)), list(a.getTerm(2)), list(a.getTerm(3)));
                action.setResult(true);
            } else {
                action.setResult(false);
                action.setFailureReason(ASSyntax.createAtom("unknown_action"), "unknown action " + a);
            }
        } catch (IOException | IllegalArgumentException e) {
            action.setResult(false);
            action.setFailureReason(ASSyntax.createAtom("request_failed"), e.getMessage());
        }
        actionExecuted(action);
    }

    private void request(Term tag, String type, List<Param> filter, List<Param> params) throws IOException {
        Description.Component emu = null;
        Description.Service entry = null;
        for (Description.Component c : body.components()) {
            for (Description.Service e : c.consumes()) {
                if (ActuatorEmulator.keyword(e.type()).equals(ActuatorEmulator.keyword(type))
                        && filter.stream().allMatch(f -> e.param(f.name())
                                .map(v -> ActuatorEmulator.keyword(v).equals(ActuatorEmulator.keyword(f.value())))
                                .orElse(false))) {
                    emu = c;
                    entry = e;
                    break;
                }
            }
            if (emu != null) {
                break;
            }
        }
        if (emu == null) {
            throw new IllegalArgumentException("no emulator of the body consumes " + type + " with " + filter);
        }
        ActuatorEmulator em = new ActuatorEmulator(client, emu.id());
        String provider = em.provider(entry.category(), entry.type());
        String id = client.nextId();
        tags.put(id, tag);
        types.put(id, type);
        client.request(Signal.builder().id(id).sender(emu.id()).receiver(provider)
                        .service(entry.category(), entry.type()).params(params))
                .whenComplete((s, e) -> answer(id, s, e));
    }

    private static String text(Term t) {
        if (t instanceof StringTerm s) {
            return s.getString();
        }
        if (t instanceof NumberTerm n) {
            try {
                double d = n.solve();
                return d == Math.rint(d) && Math.abs(d) < 1e15 ? Long.toString((long) d) : Double.toString(d);
            } catch (Exception e) {
                return t.toString();
            }
        }
        return t.toString();
    }

    private static List<Param> list(Term t) {
        if (!t.isList()) {
            throw new IllegalArgumentException("not a list of param(Name, Value): " + t);
        }
        List<Param> out = new ArrayList<>();
        for (Term x : (ListTerm) t) {
            if (!(x instanceof Structure s) || !s.getFunctor().equals("param") || s.getArity() != 2) {
                throw new IllegalArgumentException("not param(Name, Value): " + x);
            }
            out.add(new Param(text(s.getTerm(0)), text(s.getTerm(1))));
        }
        return out;
    }

    // ------------------------------------------------------------------ AgArch

    @Override
    public String getAgName() {
        return name;
    }

    @Override
    public boolean isRunning() {
        return running;
    }

    @Override
    public boolean canSleep() {
        return events.isEmpty();
    }

    @Override
    public void sendMsg(Message m) {
        throw new UnsupportedOperationException("an EVATAR-embodied agent talks through its body only");
    }

    @Override
    public void broadcast(Message m) {
        throw new UnsupportedOperationException("an EVATAR-embodied agent talks through its body only");
    }

    @Override
    public void checkMail() {
    }

    /**
     * Runs one agent: {@code EvatarAgent ASL BODY PAIRING ENTITY CREDENTIAL (HOST:PORT... | --stdio)}.
     * With {@code --stdio} it speaks on stdin/stdout, as a program started by EVATAR's port connector.
     */
    public static void main(String[] args) throws Exception {
        if (args.length < 6) {
            System.err.println("usage: EvatarAgent ASL BODY.xml PAIRING ENTITY CREDENTIAL (HOST:PORT...|--stdio)");
            System.exit(2);
        }
        boolean stdio = args[5].equals("--stdio");
        if (stdio) {
            org.evatar.client.Transport.redirectSystemOut();
        }
        Description body = Description.parse(Files.readAllBytes(Path.of(args[1]))).withEntityId(args[3]);
        EvatarClient.Options o = new EvatarClient.Options().pairing(args[2]).role("agent").entityId(args[3])
                .credential(args[4]);
        if (!stdio) {
            for (int i = 5; i < args.length; i++) {
                int c = args[i].lastIndexOf(':');
                o.endpoint(args[i].substring(0, c), Integer.parseInt(args[i].substring(c + 1)));
            }
            o.ha(args.length > 6);
        }
        EvatarAgent a = fromFile(o, body, Path.of(args[0]));
        if (stdio) {
            a.startStdio();
        } else {
            a.start();
        }
        String why = a.client().awaitClosed(Duration.ofDays(365));
        System.err.println("EVATAR connection closed: " + why);
        a.stop();
    }

}
