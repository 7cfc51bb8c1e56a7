%% @doc Test helper: an entity process for the evatar suites. It joins a
%% pairing (so it is the process the pairing monitors and delivers to) and
%% forwards everything the pairing sends as `{entity, EntityId, Message}' to
%% the process that started it.
-module(evatar_test_entity).

-export([start/4, stop/1, kill/1, sync/1, recv/2, recv/3, drain/0, flush/1,
         description/2, signal/4, signal/5]).

%% @doc Joins `Pairing' from a new process; returns the session and that
%% process, or the join error.
-spec start(binary(), evatar:role(), binary(), binary()) ->
          {ok, evatar:session(), pid()} | {error, term()}.
start(Pairing, Role, EntityId, Credential) ->
    Parent = self(),
    Pid = spawn(fun() ->
                        Result = evatar:join(Pairing, Role, EntityId, Credential),
                        Parent ! {joined, self(), Result},
                        case Result of
                            {ok, _} -> loop(Parent, EntityId);
                            _ -> ok
                        end
                end),
    receive
        {joined, Pid, {ok, Session}} -> {ok, Session, Pid};
        {joined, Pid, Error} -> Error
    end.

loop(Parent, EntityId) ->
    receive
        {evatar, _Pairing, Message} ->
            Parent ! {entity, EntityId, Message},
            loop(Parent, EntityId);
        {sync, From, Ref} ->
            From ! {synced, Ref},
            loop(Parent, EntityId);
        stop ->
            ok
    end.

%% @doc Ends the entity process normally (the pairing sees it go down).
-spec stop(pid()) -> ok.
stop(Pid) -> wait_down(Pid, fun() -> Pid ! stop end).

%% @doc Kills the entity process and waits until it is dead.
-spec kill(pid()) -> ok.
kill(Pid) -> wait_down(Pid, fun() -> exit(Pid, kill) end).

wait_down(Pid, Action) ->
    Ref = erlang:monitor(process, Pid),
    Action(),
    receive {'DOWN', Ref, process, Pid, _} -> ok end.

%% @doc Returns once the entity process has forwarded everything it had
%% received before this call.
-spec sync(pid()) -> ok.
sync(Pid) ->
    Ref = erlang:monitor(process, Pid),
    Pid ! {sync, self(), Ref},
    receive
        {synced, Ref} -> erlang:demonitor(Ref, [flush]), ok;
        {'DOWN', Ref, process, Pid, _} -> ok
    end.

%% @doc The next message forwarded for `EntityId' (waits up to 30 s, a
%% deadline for a loaded machine that a passing test never reaches): the
%% signal or binding report, or `{Code, Reason}' for `dropped'.
-spec recv(binary(), signal | bound | dropped) -> term().
recv(EntityId, Kind) -> recv(EntityId, Kind, 30000).

%% @doc As {@link recv/2} with a wait limit; `timeout' when nothing came.
-spec recv(binary(), signal | bound | dropped, timeout()) -> term().
recv(EntityId, dropped, Wait) ->
    receive
        {entity, EntityId, {dropped, Code, Reason}} -> {Code, Reason}
    after Wait -> timeout
    end;
recv(EntityId, Kind, Wait) ->
    receive
        {entity, EntityId, {Kind, Value}} -> Value
    after Wait -> timeout
    end.

%% @doc Every forwarded message already in the mailbox, in order.
-spec drain() -> [{binary(), term()}].
drain() ->
    receive
        {entity, EntityId, Message} -> [{EntityId, Message} | drain()]
    after 0 -> []
    end.

%% @doc Syncs with each entity process, then drains the mailbox.
-spec flush([pid()]) -> [{binary(), term()}].
flush(Pids) ->
    lists:foreach(fun sync/1, Pids),
    drain().

%% @doc A description of `EntityId' with components `{Id, Services,
%% Consumes}', entries as `{Category, Type}'.
-spec description(binary(), [{binary(), [{binary(), binary()}], [{binary(), binary()}]}]) ->
          bil:description().
description(EntityId, Components) ->
    Type = case EntityId of
               <<"va", _/binary>> -> agent;
               _ -> avatar
           end,
    description(EntityId, Type, Components).

description(EntityId, Type, Components) ->
    evatar_test_fixtures:description(EntityId, Type, <<"test">>, <<>>,
                                     [evatar_test_fixtures:component(Id, Ss, Cs)
                                      || {Id, Ss, Cs} <- Components]).

%% @doc A signal with an empty body.
-spec signal(binary(), bil:signal_context(), binary(), binary()) -> bil:signal().
signal(Id, Context, Sender, Receiver) ->
    signal(Id, Context, Sender, Receiver, undefined).

%% @doc A signal answering `InReplyTo'.
-spec signal(binary(), bil:signal_context(), binary(), binary(), binary() | undefined) ->
          bil:signal().
signal(Id, Context, Sender, Receiver, InReplyTo) ->
    #{id => Id, context => Context, sender => Sender, receiver => Receiver,
      in_reply_to => InReplyTo, timestamp => erlang:system_time(millisecond),
      seq => undefined, epoch => undefined,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                parameters => [{<<"Light">>, <<"yes">>}]}}.
