%% -*- erlang -*-
%% The client of a test node's control socket (scripts/test-node-ctl.escript
%% --control SOCKET): `scripts/test-node-ctl.sh --send SOCKET COMMAND...',
%% which scripts/sim-node.sh runs for each of its commands. It sends the
%% command, prints the answer's lines (or a short confirmation when the answer
%% has none) and exits 0 on OK, 1 on ERROR (printed to stderr), 3 when nothing
%% answers on SOCKET. A file of its own so that each command starts a small
%% script, not the node's.
-mode(compile).

main([Path | Words]) ->
    send(Path, Words);
main([]) ->
    io:format(standard_error, "usage: test-node-ctl.sh --send SOCKET COMMAND...~n", []),
    halt(2).

send(Path, Words) ->
    case gen_tcp:connect({local, Path}, 0, [local, binary, {packet, line}, {active, false}],
                         5000) of
        {ok, S} ->
            ok = gen_tcp:send(S, [lists:join(" ", Words), $\n]),
            answer(S, Words, false);
        {error, Why} ->
            io:format(standard_error, "no simulated node answers on ~s (~0p): start one with "
                      "scripts/sim-node.sh start~n", [Path, Why]),
            halt(3)
    end.

answer(S, Words, Printed) ->
    case gen_tcp:recv(S, 0) of
        {ok, <<"OK\n">>} ->
            _ = [io:format("~s~n", [confirmation(Words)]) || not Printed],
            halt(0);
        {ok, <<"ERROR", _/binary>> = E} -> io:format(standard_error, "~s", [E]), halt(1);
        {ok, Line} -> io:format("~s", [Line]), answer(S, Words, true);
        {error, Why} ->
            io:format(standard_error, "the node closed the connection (~0p)~n", [Why]),
            halt(1)
    end.

%% What `sim-node.sh COMMAND' prints when the node's answer has no lines.
confirmation(["mute", C]) -> ["ok muted ", C, " (it swallows requests until unmute)"];
confirmation(["unmute", C]) -> ["ok unmuted ", C];
confirmation(["disconnect", E]) -> ["ok disconnected ", E, " (away until reconnect)"];
confirmation(["disconnect", E, Ms]) -> ["ok disconnected ", E, " for ", Ms, " ms"];
confirmation(["reconnect", E]) -> ["ok reconnecting ", E, " (see links)"];
confirmation(["detach", C]) -> ["ok detached ", C];
confirmation(["attach", C]) -> ["ok attached ", C];
confirmation(["pause"]) -> "ok clock paused (resume starts it)";
confirmation(["resume"]) -> "ok clock running";
confirmation(["speed", N]) -> ["ok speed ", N, ", clock paused (resume starts it)"];
confirmation(["run_until", T]) -> ["ok clock ran to ", T, " and is paused (resume starts it)"];
confirmation(["outcome"]) -> "no outcome yet: no light change, e-mail, photo or sound";
confirmation(["links"]) -> "no links";
confirmation(["stop"]) -> "ok stopped";
confirmation(Words) -> ["ok " | lists:join(" ", Words)].
