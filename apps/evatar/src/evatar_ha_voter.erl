%% @doc Internal. This node's voter: it answers the pairings' vote and
%% registration requests (from every node's instances, `evatar_ha_proto_v1')
%% with `evatar_ha_core:answer/2' and keeps what it promised in
%% `evatar_ha_promises', on disc when the node has a data directory (read
%% back at boot, before any request is answered). A grant is sent only once
%% its record is on the device: requests that wait in the mailbox are
%% answered together, with one fdatasync (a takeover storm asks for
%% hundreds at once). A record that cannot be written (a full disk) grants
%% nothing; the node says `promise_not_persisted' once, and
%% `promises_persisted' when writes succeed again.
%%
%% The requests arrive at `evatar_cluster' (the address every version of
%% the protocol uses), which hands them on at once: the disc writes and the
%% decisions of a storm happen here, and the membership process, whose
%% heartbeats and ticks the whole cluster's view depends on, never waits
%% behind them. It runs at high priority too: in a storm every instance
%% waits on its answers against a deadline (2 x suspect_ms for a
%% registration), behind hundreds of pairing processes otherwise.
-module(evatar_ha_voter).
-behaviour(gen_server).

-export([start_link/0]).
-export([init/1, handle_continue/2, handle_call/3, handle_cast/2, handle_info/2]).

-include_lib("kernel/include/logger.hrl").

%% This node's votes: {PairingId, evatar_ha_core:record()}.
-define(VOTES, evatar_ha_votes).
%% Requests answered with one write at most.
-define(BATCH, 512).

-record(s, {%% The promises on disc; undefined while they could not be read.
            promises :: evatar_ha_promises:log() | undefined,
            %% Why the last write (or read) of promises failed, if it did.
            unwritable = false :: false | term()}).

%% @doc Starts the voter, registered as `evatar_ha_voter'.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @private
-spec init([]) -> {ok, #s{}, {continue, load_promises}}.
init([]) ->
    _ = ets:new(?VOTES, [named_table, protected, set]),
    %% Ahead of the pairings in the run queue, as evatar_cluster: every
    %% election and registration in the cluster waits for its answers
    %% against a deadline, and its work is only what they asked.
    _ = process_flag(priority, high),
    {ok, #s{}, {continue, load_promises}}.

%% @private
-spec handle_continue(load_promises, #s{}) -> {noreply, #s{}}.
handle_continue(load_promises, S) ->
    {noreply, load_promises(S)}.

%% @private
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(_Request, _From, S) ->
    {reply, {error, unknown_call}, S}.

%% @private
-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) ->
    {noreply, S}.

%% @private
-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({evatar_ha, 1, {vote, Id, Ec, Cand, _Claim, _Active, _Dead}} = Msg, S)
  when is_binary(Id), is_integer(Ec), is_pid(Cand) ->
    {noreply, answer([Msg | more_requests(?BATCH - 1)], S)};
handle_info({evatar_ha, 1, {restore_vote, Id, Ec, Cand, NoneOn}} = Msg, S)
  when is_binary(Id), is_integer(Ec), is_pid(Cand), is_list(NoneOn) ->
    {noreply, answer([Msg | more_requests(?BATCH - 1)], S)};
handle_info({evatar_ha, 1, {register, Id, E, Seq, From}} = Msg, S)
  when is_binary(Id), is_integer(E), is_integer(Seq), is_pid(From) ->
    {noreply, answer([Msg | more_requests(?BATCH - 1)], S)};
handle_info(_Msg, S) ->
    {noreply, S}.

load_promises(S) ->
    Dir = evatar_ha_promises:dir(),
    case evatar_ha_promises:open(Dir) of
        {ok, Log, Entries} ->
            true = ets:insert(?VOTES, Entries),
            S#s{promises = Log};
        {error, Reason} ->
            unwritable(Reason, 0, S)
    end.


%% The requests waiting behind the first, answered with it.
more_requests(0) ->
    [];
more_requests(N) ->
    receive
        {evatar_ha, 1, {vote, Id, Ec, Cand, _, _, _}} = Msg
          when is_binary(Id), is_integer(Ec), is_pid(Cand) ->
            [Msg | more_requests(N - 1)];
        {evatar_ha, 1, {restore_vote, Id, Ec, Cand, NoneOn}} = Msg
          when is_binary(Id), is_integer(Ec), is_pid(Cand), is_list(NoneOn) ->
            [Msg | more_requests(N - 1)];
        {evatar_ha, 1, {register, Id, E, Seq, From}} = Msg
          when is_binary(Id), is_integer(E), is_integer(Seq), is_pid(From) ->
            [Msg | more_requests(N - 1)]
    after 0 ->
            []
    end.

%% Decides every request in order (each against the records the ones
%% before changed), writes the changed records, then replies: a grant of a
%% pairing whose record changed in this batch only once that is durable.
answer(Msgs, S0) ->
    S = case S0#s.promises of
            undefined -> load_promises(S0);
            _ -> S0
        end,
    {Changed, Replies} = lists:foldl(fun decide/2, {#{}, []}, Msgs),
    case write(maps:to_list(Changed), S) of
        {ok, S1} ->
            _ = [reply(R) || {_Durable, R} <- lists:reverse(Replies)],
            S1;
        {error, Reason, S1} ->
            Lost = [R || {true, R} <- Replies],
            _ = [reply(R) || {false, R} <- lists:reverse(Replies)],
            unwritable(Reason, length(Lost), S1)
    end.

decide({evatar_ha, 1, {vote, Id, Ec, Cand, Claim, Active, Dead}}, {Changed, Replies}) ->
    Record = record(Id, Changed),
    Blocked = lists:any(fun serving/1, [P || P <- evatar_ha_core:blockers(Record, Cand, Active,
                                                                          Dead),
                                             is_pid(P)]),
    Effects = evatar_ha_core:answer({vote, Ec, Cand, Claim, Blocked}, Record),
    effects(Effects, Id, {vote_reply, Cand, Id, Ec}, Changed, Replies);
decide({evatar_ha, 1, {restore_vote, Id, Ec, Cand, NoneOn}}, {Changed, Replies}) ->
    Record = record(Id, Changed),
    Blocked = lists:any(fun serving/1,
                        [P || P <- evatar_ha_core:restore_blockers(
                                          Record, Cand, NoneOn, fun node_of/1,
                                          local_instance(Id)),
                              is_pid(P)]),
    Effects = evatar_ha_core:answer({restore_vote, Ec, Cand, Blocked}, Record),
    effects(Effects, Id, {vote_reply, Cand, Id, Ec}, Changed, Replies);
decide({evatar_ha, 1, {register, Id, E, Seq, From}}, {Changed, Replies}) ->
    Effects = evatar_ha_core:answer({register, E, Seq, From}, record(Id, Changed)),
    effects(Effects, Id, {register_reply, From, Id, {E, Seq}}, Changed, Replies).

effects([{persist, R} | Rest], Id, To, Changed, Replies) ->
    effects(Rest, Id, To, Changed#{Id => R}, Replies);
effects([{reply, {refused, _} = Refused}], _Id, To, Changed, Replies) ->
    {Changed, [{false, {To, Refused}} | Replies]};
effects([{reply, Yes}], Id, To, Changed, Replies) ->
    {Changed, [{is_map_key(Id, Changed), {To, Yes}} | Replies]}.

reply({{vote_reply, Cand, Id, Ec}, Result}) ->
    ok = evatar_ha_proto_v1:vote_reply(Cand, Id, Ec, node(), Result);
reply({{register_reply, From, Id, Claim}, Result}) ->
    ok = evatar_ha_proto_v1:register_reply(From, Id, Claim, node(), Result).

write([], S) ->
    {ok, S};
write(_Entries, #s{promises = undefined, unwritable = Reason} = S) ->
    {error, Reason, S};
write(Entries, #s{promises = Log} = S) ->
    case evatar_ha_promises:write(Log, Entries) of
        {ok, Log1} ->
            true = ets:insert(?VOTES, Entries),
            _ = case S#s.unwritable of
                    false -> ok;
                    Was -> ?LOG_NOTICE(#{what => promises_persisted, after_error => Was})
                end,
            {ok, compact(S#s{promises = Log1, unwritable = false})};
        {error, Reason, Log1} ->
            {error, Reason, S#s{promises = Log1}}
    end.

compact(#s{promises = Log} = S) ->
    case evatar_ha_promises:needs_compaction(Log, ets:info(?VOTES, size)) of
        true ->
            case evatar_ha_promises:compact(Log, ets:tab2list(?VOTES)) of
                {ok, Log1} ->
                    S#s{promises = Log1};
                {error, Reason, Log1} ->
                    ?LOG_WARNING(#{what => promises_not_compacted, reason => Reason}),
                    S#s{promises = Log1}
            end;
        false ->
            S
    end.

%% Said once, until writes succeed again.
unwritable(Reason, Lost, #s{unwritable = false} = S) ->
    ?LOG_ERROR(#{what => promise_not_persisted, dir => evatar_ha_promises:dir(),
                 reason => Reason, not_granted => Lost,
                 hint => "this node grants no vote and accepts no registration until it can "
                         "write to EVATAR_DATA_DIR again; the others decide without it"}),
    S#s{unwritable = Reason};
unwritable(_Reason, _Lost, S) ->
    S.

record(Id, Changed) ->
    case Changed of
        #{Id := R} -> R;
        #{} -> record(Id)
    end.

record(Id) ->
    case ets:lookup(?VOTES, Id) of
        [{_, R}] -> R;
        [] -> evatar_ha_core:new_record()
    end.

local_instance(Id) ->
    case evatar_registry:role(Id) of
        #{pid := Pid, role := Role} -> {Pid, Role};
        none ->
            %% Not published yet: starting.
            case evatar_registry:whereis_name(Id) of
                undefined -> undefined;
                Pid -> {Pid, starting}
            end
    end.

node_of(Pid) when is_pid(Pid) -> node(Pid);
node_of(_) -> undefined.

%% Whether an instance may still be serving, as far as this node can tell:
%% a local process that is alive, or a remote one whose node is heard.
serving(Pid) when node(Pid) =:= node() -> is_process_alive(Pid);
serving(Pid) -> evatar_cluster:alive_now(node(Pid)).
